"""Write autopilot/px4_parameters.json: the names of PX4's parameters, with the PX4 versions they
come from, so the bundled autopilot can tell a PX4 parameter it does not model (accepted without
effect) from a name PX4 does not have (refused).

The names come from the parameter reference PX4 generates from its parameter definitions (the
module.yaml files and PARAM_DEFINE_* in *_params.c, plus the per-board names generated from them,
such as PWM_MAIN_FUNC1) with `make parameters_metadata` and keeps in git: PX4-Autopilot's
docs/en/advanced_config/parameter_reference.md, or before the docs moved in, PX4-user_guide's
en/advanced_config/parameter_reference.md. It is read with git at each revision given, so no
checkout or build is needed; the names are the union, since a user's parameter file may come from
any of them. The file in the repository comes from PX4's main branch and from PX4 1.14, the
version the UAV Testing Competition's parameter files were written for:

    python scripts/px4_parameter_names.py \
        --source github.com/PX4/PX4-Autopilot PATH/TO/PX4-Autopilot main \
        --source github.com/PX4/PX4-user_guide PATH/TO/PX4-user_guide v1.14 > autopilot/px4_parameters.json
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys

REFERENCES = ("en/advanced_config/parameter_reference.md", "docs/en/advanced_config/parameter_reference.md")
# PX4's generator wrote HTML tables (`<strong id="NAME">`) up to 2024, then headings (`### NAME (`TYPE`) {#NAME}`).
NAME = re.compile(r'<strong id="([A-Za-z0-9_]+)">|^### [A-Za-z0-9_]+ \(`\w+`\) \{#([A-Za-z0-9_]+)\}', re.MULTILINE)


def _git(repository: str, *arguments: str) -> str:
    return subprocess.run(["git", "-C", repository, *arguments], check=True, capture_output=True, text=True).stdout


def names_at(repository: str, revision: str) -> tuple[dict[str, str], list[str]]:
    """Where the reference was read at `revision`, and the parameter names in it."""
    commit = _git(repository, "rev-parse", f"{revision}^{{commit}}").strip()
    for path in REFERENCES:
        try:
            text = _git(repository, "show", f"{commit}:{path}")
        except subprocess.CalledProcessError:
            continue
        names = sorted({a or b for a, b in NAME.findall(text)})
        if not names:
            sys.exit(f"{revision}:{path}: no parameter names found: has PX4's markdown generator changed its layout?")
        date, subject = _git(repository, "log", "-1", "--format=%cs%n%s", commit, "--", path).splitlines()
        return {"revision": revision, "commit": commit, "path": path, "reference_updated": date, "commit_subject": subject, "names": len(names)}, names
    sys.exit(f"{revision}: none of {', '.join(REFERENCES)} in {repository}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", nargs=3, action="append", required=True, metavar=("ORIGIN", "REPOSITORY", "REVISION"),
                        help="where the repository comes from (recorded, e.g. github.com/PX4/PX4-Autopilot), a git repository "
                             "(work tree or bare) of PX4-Autopilot or of PX4's user guide, and the revision to read; repeatable")
    args = parser.parse_args(argv)
    sources, names = [], set()
    for origin, repository, revision in args.source:
        source, found = names_at(repository, revision)
        sources.append({"origin": origin, **source})
        names.update(found)
    document = {
        "about": "Names of PX4's parameters, from the parameter reference PX4 generates from its parameter definitions "
                 "(module.yaml files, PARAM_DEFINE_* in *_params.c), at the revisions below; the union, since a "
                 "parameter file may come from any of them. Data, not PX4 code. Regenerate with scripts/px4_parameter_names.py.",
        "sources": sources,
        "names": sorted(names),
    }
    json.dump(document, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
