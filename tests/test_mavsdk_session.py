"""The harness's MAVSDK client where it decides something itself: arming a SUT that denies it."""

from __future__ import annotations

import pytest
from mavsdk.plugins.action.action import ActionError, ActionResult

from harness.flight.mavsdk_session import MavsdkSession


class ScriptedAction:
    """MAVSDK's action plugin as far as arming goes, answering arm() from a script."""

    def __init__(self, answers):
        self.answers = list(answers)
        self.attempts = 0

    def arm(self):
        self.attempts += 1
        answer = self.answers.pop(0)
        if answer != ActionResult.SUCCESS:
            raise ActionError(answer, "arm()")


def session_with(action: ScriptedAction) -> MavsdkSession:
    session = MavsdkSession.__new__(MavsdkSession)
    session.action = action
    return session


def test_a_denied_arming_is_asked_again_within_the_window():
    action = ScriptedAction([ActionResult.COMMAND_DENIED] * 3 + [ActionResult.SUCCESS])
    session_with(action).arm(retry_for_s=5.0)
    assert action.attempts == 4


def test_a_sut_that_keeps_denying_is_believed_once_the_window_is_over():
    action = ScriptedAction([ActionResult.COMMAND_DENIED] * 100)
    with pytest.raises(ActionError) as denied:
        session_with(action).arm(retry_for_s=0.25)
    assert denied.value.result == ActionResult.COMMAND_DENIED
    assert 2 <= action.attempts <= 5


def test_without_a_window_the_first_denial_counts():
    action = ScriptedAction([ActionResult.COMMAND_DENIED, ActionResult.SUCCESS])
    with pytest.raises(ActionError):
        session_with(action).arm(retry_for_s=0.0)
    assert action.attempts == 1


@pytest.mark.parametrize("answer", [ActionResult.TIMEOUT, ActionResult.NO_SYSTEM, ActionResult.COMMAND_DENIED_NOT_LANDED])
def test_other_failures_are_not_asked_again(answer):
    action = ScriptedAction([answer, ActionResult.SUCCESS])
    with pytest.raises(ActionError):
        session_with(action).arm(retry_for_s=5.0)
    assert action.attempts == 1
