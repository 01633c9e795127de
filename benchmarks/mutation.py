"""Mutation testing: how many small planted bugs do the tests of each module miss?

Runs mutmut 3 once per module, each in its own scratch folder, mutating only that module's
files and running only the tests that cover it (mutmut maps each mutated function to the tests
that call it, and runs those), then prints per module: mutants made, killed, survived, not
covered by any test, timed out, and the survival rate
``(survived + not covered) / (killed + survived + not covered + timed out)``.
The survivors (with their diffs) go to ``--out`` for reading. Mutants that mutmut calls
"suspicious" (its worker died by a signal) are run again in a plain pytest process and
counted as killed or survived by that run (see :func:`recheck`). ``--recheck-only`` scores
new tests against the last run's mutants without a new mutmut run.

numba kernels (``_kernels.py``) are not mutated: mutmut's trampolines cannot be compiled.

    PYTHONPATH=src nice python benchmarks/mutation.py [--modules geometry refraction ...]
        [--out mutation-out] [--max-children 2] [--timeout-s 7200]

It takes hours on two cores for all modules (calib and io are the big ones); run a few
modules at a time. The figures are in docs/testing.md.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# module -> (files to mutate, tests that exercise them, extra pytest arguments)
MODULES: dict[str, tuple[list[str], list[str]]] = {
    "geometry": (["src/sea3d/geometry/*"], ["tests/geometry"]),
    "refraction": (["src/sea3d/refraction/*"], ["tests/refraction"]),
    "rectify": (["src/sea3d/rectify/*"], ["tests/rectify"]),
    "stereo.depth": (["src/sea3d/stereo/depth.py"], ["tests/stereo"]),
    "calib": (["src/sea3d/calib/*"], ["tests/calib"]),
    "io": (["src/sea3d/io/*"], ["tests/io", "tests/cli/test_rig_cli.py"]),
}
DO_NOT_MUTATE = ["*/_kernels.py", "*/__init__.py"]
PYTEST_ARGS = ["-x", "-q", "-p", "no:cacheprovider", "-m", "not slow and not gpu and not browser"]


def _toml_list(values: list[str]) -> str:
    return "[" + ", ".join(json.dumps(v) for v in values) + "]"


def prepare(module: str, scratch: Path) -> Path:
    """A scratch copy of the project with a pyproject.toml that configures mutmut for
    ``module``."""
    mutate, tests = MODULES[module]
    work = scratch / module.replace(".", "_")
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc")
    shutil.copytree(ROOT / "src", work / "src", ignore=ignore)
    shutil.copytree(ROOT / "tests", work / "tests", ignore=ignore)
    pyproject = (ROOT / "pyproject.toml").read_text()
    pyproject += (
        "\n[tool.mutmut]\n"
        'source_paths = ["src"]\n'
        f"only_mutate = {_toml_list(mutate)}\n"
        f"do_not_mutate = {_toml_list(DO_NOT_MUTATE)}\n"
        f"pytest_add_cli_args = {_toml_list(PYTEST_ARGS)}\n"
        f"pytest_add_cli_args_test_selection = {_toml_list(tests)}\n"
    )
    (work / "pyproject.toml").write_text(pyproject)
    return work


def stats(work: Path) -> dict[str, int]:
    subprocess.run([sys.executable, "-m", "mutmut", "export-cicd-stats"], cwd=work,
                   check=False, capture_output=True)
    path = work / "mutants" / "mutmut-cicd-stats.json"
    if not path.is_file():
        return {}
    data: dict[str, int] = json.loads(path.read_text())
    return data


def results(work: Path) -> dict[str, str]:
    """``{mutant: status}`` for every mutant mutmut did not kill."""
    out = subprocess.run([sys.executable, "-m", "mutmut", "results"], cwd=work, check=False,
                         capture_output=True, text=True).stdout
    found = {}
    for line in out.splitlines():
        name, _, status = line.strip().rpartition(":")
        if name:
            found[name.strip()] = status.strip()
    return found


# Runs in the scratch's mutants/ folder with its mutated source first on the path: imports
# the heavy modules once, then forks one child per mutant that names it in MUTANT_UNDER_TEST
# (mutmut's trampolines read it at every call) and runs pytest; prints {mutant: exit code}.
_FORK_RUNNER = r"""
import json, os, sys
import numpy, scipy.spatial.transform, cv2, pytest  # noqa: F401
import sea3d.geometry  # noqa: F401
jobs = json.loads(sys.stdin.read())
out = {}
for name, args in jobs:
    pid = os.fork()
    if pid == 0:
        os.environ["MUTANT_UNDER_TEST"] = name
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.dup2(null, 2)
        os._exit(int(pytest.main(args)))
    out[name] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
print(json.dumps(out))
"""


def recheck(work: Path, names: list[str], env: dict[str, str], every_test: bool = False
            ) -> dict[str, str]:
    """Run the tests of each given mutant again, outside mutmut's fork server.

    Under mutmut 3.8 the worker that runs a mutant is killed by SIGTERM (exit -15, counted as
    "suspicious") after tests that use OpenCV or numba kernels have run, whether they passed or
    failed (measured on ``PinholeCamera.project``: a mutant that fails the tests run by hand
    and an equivalent one that passes them both came back -15). Here each mutant is run as
    mutmut would (its mutated source first on the path, ``MUTANT_UNDER_TEST`` naming it, only
    the tests that call its function, or with ``every_test`` all of the module's tests) in a
    forked plain pytest: exit 0 is a survivor, 1 a kill.
    """
    stats_path = work / "mutants" / "mutmut-stats.json"
    by_func: dict[str, list[str]] = {}
    if stats_path.is_file():
        by_func = json.loads(stats_path.read_text()).get("tests_by_mangled_function_name", {})
    module_tests = MODULES[next(m for m in MODULES if work.name == m.replace(".", "_"))][1]
    jobs = []
    for name in names:
        tests = [] if every_test else sorted(by_func.get(name.partition("__mutmut_")[0], []))
        jobs.append((name, [*PYTEST_ARGS, *(tests or module_tests)]))
    run_env = dict(env, PYTHONPATH=str(work / "mutants" / "src"))
    run_env.pop("MUTANT_UNDER_TEST", None)
    proc = subprocess.run([sys.executable, "-c", _FORK_RUNNER], cwd=work / "mutants",
                          env=run_env, input=json.dumps(jobs), capture_output=True, text=True,
                          check=False)
    codes: dict[str, int] = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout else {}
    return {n: {0: "survived", 1: "killed", 5: "no tests"}.get(codes.get(n, -1), "suspicious")
            for n in names}


def show(work: Path, name: str, cache: dict[Path, dict[str, str]]) -> str:
    """The diff of one mutant against the original function, read from the mutated source
    mutmut wrote (as ``mutmut show`` does, without starting mutmut for each)."""
    module, _, func = name.rpartition(".")
    path = work / "mutants" / "src" / Path(*module.split(".")).with_suffix(".py")
    if path not in cache:
        text = path.read_text()
        cache[path] = {node.name: ast.get_source_segment(text, node) or ""
                       for node in ast.walk(ast.parse(text))
                       if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)}
    funcs = cache[path]
    orig = funcs.get(func.rsplit("__mutmut_", 1)[0] + "__mutmut_orig", "")
    mutant = funcs.get(func, "")
    lines = difflib.unified_diff(orig.replace("__mutmut_orig", "").splitlines(),
                                 mutant.replace(func[func.rfind("__mutmut_"):], "").splitlines(),
                                 str(path.relative_to(work / "mutants")),
                                 str(path.relative_to(work / "mutants")), n=2, lineterm="")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--modules", nargs="+", default=list(MODULES), choices=list(MODULES))
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/sea3d-mutation"))
    parser.add_argument("--out", type=Path, default=Path("mutation-out"))
    parser.add_argument("--max-children", type=int, default=2)
    parser.add_argument("--timeout-s", type=float, default=4 * 3600.0,
                        help="stop a module's run after this long (its counts so far are kept)")
    parser.add_argument("--no-run", action="store_true",
                        help="no new mutmut run: score the last run in --scratch (its "
                             "'suspicious' mutants rechecked)")
    parser.add_argument("--recheck-only", action="store_true",
                        help="no new mutmut run: take the last run's mutants in --scratch, copy "
                             "today's tests into it and run every mutant that was not killed "
                             "again (what new tests kill, with the source unchanged)")
    parser.add_argument("--only", type=Path, metavar="SURVIVORS_TXT",
                        help="with --recheck-only: run only the mutants listed in an earlier "
                             "run's survivors file (--out/<module>.txt), the rest keep their "
                             "verdict")
    parser.add_argument("--match", nargs="+", metavar="TEXT",
                        help="with --only: run again only the mutants whose names contain one "
                             "of these (e.g. se3 triangulate); the others keep their verdict")
    parser.add_argument("--no-recheck", action="store_true",
                        help="leave mutmut's 'suspicious' verdicts as they are")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("SEA3D_TEST_DATA", str((ROOT / ".." / "shared" / "data").resolve()))
    env["OMP_WAIT_POLICY"] = "PASSIVE"
    rows = []
    for module in args.modules:
        t0 = time.perf_counter()
        finished = True
        if args.recheck_only or args.no_run:
            work = args.scratch / module.replace(".", "_")
            if not (work / "mutants").is_dir():
                print(f"== {module}: no earlier run in {work}; skipped", flush=True)
                continue
            if args.recheck_only:
                shutil.rmtree(work / "mutants" / "tests")
                shutil.copytree(ROOT / "tests", work / "mutants" / "tests",
                                ignore=shutil.ignore_patterns("__pycache__"))
            print(f"== {module}: the last run in {work}"
                  + (", its unkilled mutants run again with today's tests"
                     if args.recheck_only else ""), flush=True)
        else:
            work = prepare(module, args.scratch)
            print(f"== {module}: mutmut run in {work}", flush=True)
            try:
                subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children",
                                str(args.max_children)], cwd=work, env=env, check=False,
                               timeout=args.timeout_s, stdout=subprocess.DEVNULL)
            except subprocess.TimeoutExpired:
                finished = False
        st = stats(work)
        status = results(work)
        if args.recheck_only and args.only is not None:
            listed = dict(line[2:].rsplit("  [", 1) for line in args.only.read_text().splitlines()
                          if line.startswith("# "))
            for n, v in status.items():
                # the earlier run's verdicts: listed ones survived, other suspicious were killed
                status[n] = listed[n].rstrip("]") if n in listed else (
                    "killed" if v == "suspicious" else v)
            todo = sorted(n for n in listed if n in status
                          and (not args.match or any(m in n for m in args.match)))
        elif args.recheck_only:
            todo = [n for n, v in status.items() if v in ("survived", "no tests", "suspicious")]
        else:
            todo = [n for n, v in status.items() if v == "suspicious"]
        if not args.no_recheck and todo:
            # New tests are not in mutmut's map of which tests call which function: with
            # --recheck-only every one of the module's tests runs.
            status.update(recheck(work, todo, env, every_test=args.recheck_only))
        minutes = (time.perf_counter() - t0) / 60
        count = {k: sum(v == k for v in status.values())
                 for k in ("survived", "no tests", "suspicious", "timeout", "not checked")}
        total = int(st.get("total", len(status)))
        killed = total - sum(count.values())
        names = [n for n, v in status.items() if v in ("survived", "no tests")]
        cache: dict[Path, dict[str, str]] = {}
        with (args.out / f"{module}.txt").open("w") as fh:
            for name in names:
                fh.write(f"# {name}  [{status[name]}]\n{show(work, name, cache)}\n\n")
        surv, untested = count["survived"], count["no tests"]
        scored = killed + surv + untested + count["timeout"]
        rate = (surv + untested) / scored if scored else float("nan")
        rows.append((module, total, killed, surv, untested, count["timeout"],
                     count["suspicious"] + count["not checked"], rate, minutes, finished))
        print(f"   {count} ({minutes:.0f} min{'' if finished else ', stopped at the time limit'})",
              flush=True)
    print(f"\n{'module':<14}{'mutants':>8}{'killed':>8}{'survived':>9}{'no tests':>9}"
          f"{'timeout':>8}{'unscored':>9}{'survival':>9}{'minutes':>8}")
    for module, total, killed, surv, untested, timeout, unscored, rate, minutes, finished in rows:
        print(f"{module:<14}{total:8d}{killed:8d}{surv:9d}{untested:9d}{timeout:8d}{unscored:9d}"
              f"{100 * rate:8.1f}%{minutes:8.0f}{'' if finished else ' (partial)'}")
    print(f"\nsurvival = (survived + no tests) / (killed + survived + no tests + timeout); "
          f"unscored: still suspicious or never run. Survivors with their diffs: "
          f"{args.out}/<module>.txt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
