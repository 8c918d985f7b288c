"""The harness's exceptions: one root, specific subclasses that format their own message."""

from __future__ import annotations

from dataclasses import dataclass


class StellaError(Exception):
    """Root of every error the harness raises on purpose."""

    exit_code = 3


@dataclass(frozen=True)
class Problem:
    """One located problem in an input file: `file: /json/pointer: message`, or `file: message`
    for the file as a whole."""

    file: str
    pointer: str
    message: str

    def __str__(self) -> str:
        if not self.pointer:  # the whole file (or a command-line option): nothing inside to point at
            return f"{self.file}: {self.message}"
        return f"{self.file}: {self.pointer}: {self.message}"


class InputError(StellaError):
    """Bad input from the user (scenario, profile, concrete scenario, arguments)."""

    exit_code = 2

    def __init__(self, problems: list[Problem] | tuple[Problem, ...]):
        self.problems = tuple(problems)
        super().__init__("\n".join(str(p) for p in self.problems))


class InfrastructureError(StellaError):
    """A simulator or SUT process would not start or answer."""

    exit_code = 3
