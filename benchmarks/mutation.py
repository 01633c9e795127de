"""Mutation testing: how many small planted bugs do the tests of each module miss?

Runs mutmut 3 once per module, each in its own scratch folder, mutating only that module's
files and running only the tests that cover it (mutmut maps each mutated function to the tests
that call it, and runs those), then prints per module: mutants made, killed, survived, not
covered by any test, timed out, and the survival rate
``(survived + not covered) / (killed + survived + not covered + timed out)``.
The survivors (with their diffs) go to ``--out`` for reading.

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


def survivors(work: Path) -> list[str]:
    out = subprocess.run([sys.executable, "-m", "mutmut", "results"], cwd=work, check=False,
                         capture_output=True, text=True).stdout
    names = []
    for line in out.splitlines():
        name, _, status = line.strip().rpartition(":")
        if name and status.strip() in ("survived", "no tests"):
            names.append(f"{name.strip()}  [{status.strip()}]")
    return names


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
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("SEA3D_TEST_DATA", str((ROOT / ".." / "shared" / "data").resolve()))
    env["OMP_WAIT_POLICY"] = "PASSIVE"
    rows = []
    for module in args.modules:
        work = prepare(module, args.scratch)
        t0 = time.perf_counter()
        print(f"== {module}: mutmut run in {work}", flush=True)
        try:
            subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children",
                            str(args.max_children)], cwd=work, env=env, check=False,
                           timeout=args.timeout_s, stdout=subprocess.DEVNULL)
            finished = True
        except subprocess.TimeoutExpired:
            finished = False
        minutes = (time.perf_counter() - t0) / 60
        st = stats(work)
        names = survivors(work)
        cache: dict[Path, dict[str, str]] = {}
        with (args.out / f"{module}.txt").open("w") as fh:
            for name in names:
                fh.write(f"# {name}\n{show(work, name.split()[0], cache)}\n\n")
        killed, surv = st.get("killed", 0), st.get("survived", 0)
        untested, timeout = st.get("no_tests", 0), st.get("timeout", 0)
        scored = killed + surv + untested + timeout
        rate = (surv + untested) / scored if scored else float("nan")
        rows.append((module, st.get("total", 0), killed, surv, untested, timeout, rate, minutes,
                     finished))
        print(f"   {st}  ({minutes:.0f} min{'' if finished else ', stopped at the time limit'})",
              flush=True)
    print(f"\n{'module':<14}{'mutants':>8}{'killed':>8}{'survived':>9}{'no tests':>9}"
          f"{'timeout':>8}{'survival':>9}{'minutes':>8}")
    for module, total, killed, surv, untested, timeout, rate, minutes, finished in rows:
        print(f"{module:<14}{total:8d}{killed:8d}{surv:9d}{untested:9d}{timeout:8d}"
              f"{100 * rate:8.1f}%{minutes:8.0f}{'' if finished else ' (partial)'}")
    print(f"\nsurvivors with their diffs: {args.out}/<module>.txt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
