"""ArduPilot's ArduCopter SITL built from a tree (harness/firmware/builds.py's ArduPilot kind):
waf in the commit's worktree, plain or with ArduPilot's own --coverage, and the exit library a
coverage build's flights preload."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Sequence

import sut_adapter
from harness.firmware.builds import BUILD_LOG, DIGEST_LOG, BuildFailed, _keep_notes, _object_digest, _tail, _worktree, apply_patches, git
from sut_adapter.coverage import GCOV_TOOL, mark_coverage_build

# waf's lock file says which out folder its commands build in: one per configuration, so that the
# plain and the coverage build of a worktree each stay configured (configuring again recompiles all).
WAF_OUT = {False: "build", True: "build_coverage"}


def build_ardupilot(source: Path, commit: str, patches: list[Path], folder: Path, cache: Path, jobs: int | None, watch: Sequence[str],
                     worktree_command: str | None, coverage_paths: Sequence[str] | None = None, keep: bool = True) -> dict[str, str]:
    """ArduCopter SITL of the commit with the patches, by waf in the commit's worktree (as
    builds._build_px4). A coverage build compiles everything with ArduPilot's own --coverage, and carries
    the library through which its flights end in order (compile_exit_shim): its SITL acts on
    SIGTERM only when its simulated clock moves on, which nothing advances after a flight."""
    log_path = folder / (BUILD_LOG if keep else DIGEST_LOG)
    measured = coverage_paths is not None
    with open(log_path, "w") as log_file:
        tree = _worktree(source, commit, cache, log_file, worktree_command)
        touched = apply_patches(tree, patches)
        try:
            out = tree / WAF_OUT[measured]
            env = {**os.environ, "WAFLOCK": f".lock-waf_stella_{WAF_OUT[measured]}"}
            steps = [["./waf", "copter", f"-j{jobs or len(os.sched_getaffinity(0))}"]]
            if not (tree / env["WAFLOCK"]).is_file():
                # --no-submodule-update: the worktree's submodules are those made above; waf's own
                # update would reach for the network.
                steps.insert(0, ["./waf", "configure", "--board", "sitl", "--no-submodule-update", "--out", str(out),
                                 *(["--coverage"] if measured else [])])
            for argv in steps:
                log_file.write(f"$ WAFLOCK={env['WAFLOCK']} {' '.join(argv)}  (in {tree})\n")
                log_file.flush()
                if subprocess.run(argv, cwd=tree, stdout=log_file, stderr=subprocess.STDOUT, env=env).returncode != 0:
                    raise BuildFailed(f"ArduCopter {commit[:12]} with {len(patches)} patch(es)", log_path, _tail(log_path))
            build_dir = out / "sitl"
            objects = {name: digest for name in dict.fromkeys([*touched, *watch]) if (digest := _object_digest(build_dir, name))}
            if not keep:
                return objects
            (folder / "bin").mkdir()
            shutil.copy2(build_dir / "bin" / "arducopter", folder / "bin" / "arducopter")
            if measured:
                _keep_notes(tree, build_dir, folder, coverage_paths)
                mark_coverage_build(folder, GCOV_TOOL, coverage_paths, build_dir=str(build_dir), tree=str(tree),
                                    preload=str(compile_exit_shim(folder, log_file, log_path)))
        finally:
            if touched:
                git(tree, "checkout", "--", *touched, check=False)
    return objects


def compile_exit_shim(folder: Path, log_file, log_path: Path) -> Path:
    """sut_adapter/gcov_exit.c compiled into the variant: the library its flights preload, so that
    the adapter's SIGUSR1 ends ArduPilot through exit(), which writes the counters."""
    shim = folder / "lib" / "stella_gcov_exit.so"
    shim.parent.mkdir()
    argv = ["cc", "-shared", "-fPIC", "-O2", "-o", str(shim), str(Path(sut_adapter.__file__).parent / "gcov_exit.c")]
    log_file.write(f"$ {' '.join(argv)}\n")
    log_file.flush()
    if subprocess.run(argv, stdout=log_file, stderr=subprocess.STDOUT).returncode != 0:
        raise BuildFailed("the exit library of the coverage build", log_path, _tail(log_path))
    return shim
