"""Mutation testing: apply deliberate bugs to a copy of the repository and check that the tests catch them.

Each mutation (:data:`mutants.MUTATIONS`) is one exact text substitution in one file. The pattern must occur in
the file exactly ``count`` times (default once), otherwise :class:`MutationError` is raised before anything is
run: a mutation whose code has moved fails loudly instead of silently testing nothing. The substitution is
applied to a fresh copy of the repository's files (``git ls-files``: tracked and untracked-but-not-ignored, as
they are in the working tree) in a temporary directory, and pytest runs there with ``PYTHONPATH`` pointing at
the copy (so that subprocesses, e.g. the ``fenicsfoam`` console script and the demos, import the mutated code
too, ahead of the editable install).

A mutation is run against its ``targets`` (pytest node ids, fast) or, with ``--full``, against the whole fast
suite (``pytest`` with the project's default options); if the serial run passes and the mutation has
``mpi_targets`` (or with ``--full``), the ``mpi`` tests then run under ``mpirun -n 2``. Outcomes:

``caught``      a test failed (or errored, e.g. at collection);
``survived``    every test passed: the bug is not detected;
``timeout``     a run exceeded ``--timeout`` (a hang is not a test failure; reported separately);
``error``       the harness could not run the tests (no test collected, pytest usage or internal error).

By default a serial run stops at its first failure (``pytest -x``: the table names that test);
``--all-failures`` runs the targets to the end and lists every failing test (slower).

Before the mutations, the same targets run on an unmutated copy (``--no-baseline`` skips it): a failing
baseline means the results would say nothing, and the harness stops.

Run ``make mutate`` (or ``python tests/mutation/mutate.py [--full] [--all-failures] [--only NAME ...]
[--markdown FILE]``).
Exit status: 0 if every mutation was caught, 1 otherwise, 2 for a bad command line or a failing baseline.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Exit codes of pytest: 0 all passed, 1 some failed, 2 interrupted (e.g. collection errors), 3 internal error,
#: 4 usage error, 5 no tests collected.
_CAUGHT_CODES = {1, 2}
DEFAULT_TIMEOUT_S = 1800.0
#: Seconds without new output, after a test has failed, before a run is taken to hang (see ``_run``).
STALL_S = 120.0
#: The harness's own test (never run on a mutated copy).
SELF_TEST = "tests/test_mutation.py"


class MutationError(Exception):
    """A mutation cannot be applied as written (pattern missing or ambiguous, file missing)."""


@dataclass(frozen=True)
class Mutation:
    """One deliberate bug: replace ``old`` by ``new`` in ``path`` (relative to the repository root).

    ``targets`` are the pytest node ids (files or ``file::test``) run serially for a fast check; ``mpi_targets``
    the ones run under ``mpirun -n 2 ... -m mpi`` when the serial run does not catch the bug (a missing
    reduction over ranks is invisible on one rank). ``count`` is how often ``old`` must occur (all occurrences
    are replaced).
    """

    name: str
    path: str
    old: str
    new: str
    bug: str
    targets: tuple[str, ...] = ()
    mpi_targets: tuple[str, ...] = ()
    count: int = 1

    def __post_init__(self):
        if not self.targets and not self.mpi_targets:
            raise MutationError(f"mutation {self.name!r}: no targets")

    def apply(self, root: Path) -> None:
        """Substitute in the file under ``root``; raise :class:`MutationError` unless ``old`` occurs ``count`` times."""
        path = root / self.path
        if not path.is_file():
            raise MutationError(f"mutation {self.name!r}: {self.path} does not exist")
        text = path.read_text()
        found = text.count(self.old)
        if found != self.count:
            raise MutationError(f"mutation {self.name!r}: the pattern occurs {found} times in {self.path}, expected "
                                f"{self.count} (has the code moved? update tests/mutation/mutants.py):\n{self.old}")
        path.write_text(text.replace(self.old, self.new))


@dataclass
class Outcome:
    """The result of one mutation (or of the baseline)."""

    name: str
    status: str                       #: caught, survived, timeout, error
    caught_by: str = ""               #: first failing test (or the reason)
    failed: list[str] = field(default_factory=list)  #: every failing test of the run that caught the bug
    collected: int | None = None      #: tests that run took part in (failed + passed + skipped ...), if it says
    stopped_at_first: bool = True     #: the catching run stopped at its first failure (pytest -x)
    seconds: float = 0.0
    runs: list[str] = field(default_factory=list)   #: the commands run
    output: str = ""                  #: the tail of the last run's output

    @property
    def caught(self) -> bool:
        return self.status == "caught"


def repository_files(root: Path = ROOT) -> list[str]:
    """The working tree's files (paths relative to ``root``): tracked and untracked-but-not-ignored ones in a git
    checkout; elsewhere (e.g. in a copy made by this harness) every file outside hidden folders, ``out`` and
    caches."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=root,
                             capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        skip = {"out", "__pycache__"}
        return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and not any(
            part.startswith(".") or part in skip or part.endswith(".egg-info") for part in p.relative_to(root).parts))
    return sorted(p for p in out.decode().split("\0") if p and (root / p).is_file())


def copy_repository(dest: Path, root: Path = ROOT, files: Sequence[str] | None = None) -> Path:
    """Copy the repository's files into ``dest`` (created) and return it."""
    for name in files if files is not None else repository_files(root):
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / name, target)
    return dest


def check_patterns(mutations: Iterable[Mutation], root: Path = ROOT) -> None:
    """Raise :class:`MutationError` unless every mutation applies to the files under ``root`` as written."""
    problems = []
    for m in mutations:
        text = (root / m.path).read_text() if (root / m.path).is_file() else None
        if text is None:
            problems.append(f"{m.name}: {m.path} does not exist")
        elif text.count(m.old) != m.count:
            problems.append(f"{m.name}: pattern occurs {text.count(m.old)} times in {m.path}, expected {m.count}")
        for target in m.targets + m.mpi_targets:
            if not (root / target.split("::")[0]).is_file():
                problems.append(f"{m.name}: target {target} does not exist")
    names = [m.name for m in mutations]
    problems += [f"duplicate mutation name {n!r}" for n in sorted({n for n in names if names.count(n) > 1})]
    if problems:
        raise MutationError("mutations that cannot be applied as written:\n  " + "\n  ".join(problems))


def _environment(copy: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(copy), *filter(None, [env.get("PYTHONPATH")])])
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
               OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_btl_vader_single_copy_mechanism="none",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    env.pop("PYTEST_ADDOPTS", None)
    return env


def _failures(output: str, mpi: bool = False) -> list[str]:
    """Every failed test of pytest's short summary (``FAILED id``/``ERROR id`` lines), in order, without repeats.

    Under mpirun (``mpi``) every rank prints the summary and the ranks' lines may interleave: an id cut short
    (not a node id ``file::test`` or a file, or a strict prefix of another failing id) is dropped."""
    found = list(dict.fromkeys(re.findall(r"^(?:FAILED|ERROR) (\S+)", output, re.MULTILINE)))
    found = [t for t in found if "::" in t or t.endswith(".py")]
    if mpi:
        found = [t for t in found if not any(u != t and u.startswith(t) for u in found)]
    return found


def _grouped(tests: Sequence[str]) -> list[str]:
    """Node ids with their parametrizations folded: ``file::test`` (× k when k parametrized cases failed)."""
    counts: dict[str, int] = {}
    for t in tests:
        base = t.split("[", 1)[0]
        counts[base] = counts.get(base, 0) + 1
    return [f"`{base}`" + (f" × {k}" if k > 1 else "") for base, k in counts.items()]


def _collected(output: str) -> int | None:
    """The number of tests in pytest's final line (``3 failed, 40 passed, 2 skipped in 9.1s``), else None."""
    lines = [line for line in output.splitlines() if re.search(r"\b(passed|failed|error|errors)\b.* in [\d.]+s", line)]
    if not lines:
        return None
    counts = re.findall(r"(\d+) (?:failed|passed|skipped|xfailed|xpassed|errors?)\b", lines[-1])
    return sum(int(c) for c in counts)


def _first_failure(output: str) -> str:
    """The first failed test: from pytest's short summary (``FAILED id``) or, without one (a run killed after a
    failure), from the verbose progress (``id FAILED``); else ''."""
    summary = re.search(r"^(?:FAILED|ERROR) (\S+)", output, re.MULTILINE)
    if summary:
        return summary.group(1)
    match = _FAILED.search(output)
    return (match.group(1) or match.group(2)) if match else ""


def pytest_commands(mutation: Mutation, full: bool, python: str = sys.executable, nproc: int = 2,
                    stop_first: bool = True) -> list[list[str]]:
    """The serial and (if any) the MPI pytest command lines for ``mutation``, in the order they are run.

    ``stop_first=False`` runs every serial target to the end (every failing test is then reported)."""
    # the harness's own test applies mutations to the unmutated code: it cannot run on a mutated copy
    base = ["-m", "pytest", "-p", "no:cacheprovider", "-rfE", "--color=no", f"--ignore={SELF_TEST}"]
    # serially, stop at the first failure; under MPI never (-x): a rank that stops while the others go on to the
    # next test's collectives would leave them waiting forever. -v names each test with its outcome.
    serial = [python, *base, "-q", *(("-x",) if stop_first else ()), *(mutation.targets if not full else ())]
    commands = [serial] if (mutation.targets or full) else []
    if mutation.mpi_targets or full:
        mpi = ["mpirun", "-n", str(nproc), python, "-m", "mpi4py", *base, "-v",
               "-m", "mpi and not slow" if full else "mpi", *(mutation.mpi_targets if not full else ())]
        commands.append(mpi)
    return commands


#: Exit "code" of a run killed because it stalled after a test had failed (see :func:`_run`).
STALLED_AFTER_FAILURE = -1
_FAILED = re.compile(r"(?:^|\s)(\S+::\S+) (?:FAILED|ERROR)\b|^(?:FAILED|ERROR) (\S+)", re.MULTILINE)


def _run(command: list[str], cwd: Path, env: dict[str, str], timeout: float, stall: float = STALL_S
         ) -> tuple[int | None, str]:
    """Run ``command`` in its own process group; return ``(exit code, output)``.

    The whole group (mpirun and its ranks) is killed after ``timeout`` seconds (exit code ``None``), or once a
    test has failed and the output has not changed for ``stall`` seconds (:data:`STALLED_AFTER_FAILURE`): under
    MPI a test that fails on one rank only (e.g. a value not summed over ranks) lets that rank skip a collective
    the other one then waits in forever; the failure is what the run was for.
    """
    with tempfile.NamedTemporaryFile("w+") as out:
        proc = subprocess.Popen(command, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        start = last_change = time.monotonic()
        size, code = -1, None
        while True:
            try:
                code = proc.wait(timeout=2.0)
                break
            except subprocess.TimeoutExpired:
                pass
            now = time.monotonic()
            current = os.path.getsize(out.name)
            if current != size:
                size, last_change = current, now
            stalled = now - last_change > stall and _FAILED.search(Path(out.name).read_text(errors="replace"))
            if now - start > timeout or stalled:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                code = STALLED_AFTER_FAILURE if stalled else None
                break
        return code, Path(out.name).read_text(errors="replace")


def run_in_copy(mutation: Mutation, *, full: bool = False, root: Path = ROOT, timeout: float = DEFAULT_TIMEOUT_S,
                files: Sequence[str] | None = None, keep: bool = False, apply: bool = True,
                stop_first: bool = True) -> Outcome:
    """Apply ``mutation`` (unless ``apply`` is False: the baseline) to a fresh copy and run its tests there
    (``stop_first=False``: every serial target to the end, so that every failing test is recorded)."""
    start = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(prefix=f"fenicsfoam-mutant-{mutation.name}-"))
    outcome = Outcome(mutation.name, "survived")
    try:
        copy = copy_repository(tmp / "repo", root, files)
        if apply:
            mutation.apply(copy)
        env = _environment(copy)
        for command in pytest_commands(mutation, full, stop_first=stop_first):
            outcome.runs.append(" ".join(command))
            code, output = _run(command, copy, env, timeout)
            outcome.output = output[-4000:]
            if code is None:
                outcome.status, outcome.caught_by = "timeout", f"no result within {timeout:g} s"
                break
            if code in _CAUGHT_CODES or code == STALLED_AFTER_FAILURE:
                outcome.status = "caught"
                where = _first_failure(output) or "(collection or import error)"
                outcome.caught_by = where + (" [mpirun -n 2]" if command[0] == "mpirun" else "")
                outcome.failed = _failures(output, mpi=command[0] == "mpirun")
                outcome.collected = _collected(output)
                outcome.stopped_at_first = "-x" in command
                if code == STALLED_AFTER_FAILURE:
                    outcome.caught_by += ", then the ranks desynchronised (killed)"
                break
            if code != 0:
                outcome.status = "error"
                outcome.caught_by = f"pytest exit code {code} ({' '.join(command[-3:])})"
                break
    finally:
        outcome.seconds = time.perf_counter() - start
        if keep:
            outcome.output += f"\n(copy kept in {tmp})"
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return outcome


def run_mutations(mutations: Sequence[Mutation], *, full: bool = False, root: Path = ROOT,
                  timeout: float = DEFAULT_TIMEOUT_S, baseline: bool = True, keep: bool = False,
                  progress: Callable[[Outcome], None] | None = None, stop_first: bool = True) -> list[Outcome]:
    """Check the patterns, run the baseline (unless disabled), then every mutation; return the outcomes.

    Raises :class:`MutationError` when a pattern does not apply or the baseline fails.
    """
    check_patterns(mutations, root)
    files = repository_files(root)
    if baseline:
        union = Mutation("baseline", mutations[0].path, "", "", "none",
                         targets=tuple(dict.fromkeys(t for m in mutations for t in m.targets)),
                         mpi_targets=tuple(dict.fromkeys(t for m in mutations for t in m.mpi_targets)))
        base = run_in_copy(union, full=full, root=root, timeout=timeout, files=files, apply=False)
        if progress:
            progress(base)
        if base.status != "survived":
            raise MutationError(f"the unmutated tests do not pass ({base.status}: {base.caught_by}); fix them first:"
                                f"\n{base.output}")
    outcomes = []
    for mutation in mutations:
        outcome = run_in_copy(mutation, full=full, root=root, timeout=timeout, files=files, keep=keep,
                              stop_first=stop_first)
        outcomes.append(outcome)
        if progress:
            progress(outcome)
    return outcomes


def _failing_count(o: Outcome) -> str:
    """How many of the catching run's tests failed: ``k / n``, or why that is not known."""
    if not o.caught:
        return "—"
    if o.stopped_at_first:
        return "stopped at the 1st"
    if not o.failed:
        return "≥ 1"
    return f"{len(o.failed)} / {o.collected}" if o.collected else str(len(o.failed))


def markdown_table(mutations: Sequence[Mutation], outcomes: Sequence[Outcome]) -> str:
    """The outcomes as a Markdown table (one row per mutation, in the order given); when the runs were not
    stopped at their first failure, every failing test follows, per mutation."""
    lines = ["| mutation | file | deliberate bug | result | first failing test | tests failing | s |",
             "|---|---|---|---|---|---:|---:|"]
    for m, o in zip(mutations, outcomes):
        lines.append(f"| `{m.name}` | `{m.path}` | {m.bug} | **{o.status}** | "
                     f"{('`' + o.caught_by + '`') if o.caught_by else '—'} | {_failing_count(o)} | {o.seconds:.0f} |")
    caught = sum(o.caught for o in outcomes)
    lines.append("")
    lines.append(f"{caught} of {len(outcomes)} mutations caught.")
    listed = [(m, o) for m, o in zip(mutations, outcomes) if o.caught and len(o.failed) > 1]
    if listed:
        lines += ["", "Every failing test of the run that caught each bug, when more than one (× k: k parametrized "
                  "cases):", ""]
        for m, o in listed:
            lines.append(f"- `{m.name}`: " + ", ".join(_grouped(o.failed)))
    return "\n".join(lines)


def _load_mutants():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        import mutants
    finally:
        sys.path.pop(0)
    return mutants.MUTATIONS


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: run the curated mutations and print the table."""
    mutations = _load_mutants()
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--full", action="store_true", help="run the whole fast suite (and its mpi subset) per mutation")
    p.add_argument("--only", nargs="+", metavar="NAME", help="run only these mutations")
    p.add_argument("--list", action="store_true", help="list the mutations and exit")
    p.add_argument("--check", action="store_true", help="only check that every pattern applies, run nothing")
    p.add_argument("--no-baseline", action="store_true", help="skip the run on the unmutated copy")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, help="seconds per pytest run")
    p.add_argument("--keep", action="store_true", help="keep the mutated copies (their path is printed)")
    p.add_argument("--all-failures", action="store_true",
                   help="run every serial target to the end (no -x) and list every failing test (slower)")
    p.add_argument("--markdown", type=Path, metavar="FILE", help="also write the table to FILE")
    args = p.parse_args(argv)
    if args.only:
        unknown = sorted(set(args.only) - {m.name for m in mutations})
        if unknown:
            p.error(f"unknown mutation(s) {unknown}; valid: {', '.join(m.name for m in mutations)}")
        mutations = [m for m in mutations if m.name in args.only]
    if args.list:
        for m in mutations:
            print(f"{m.name:28s} {m.path:32s} {m.bug}")
        return 0
    try:
        check_patterns(mutations)
        if args.check:
            print(f"all {len(mutations)} mutation patterns apply")
            return 0

        def progress(o: Outcome) -> None:
            print(f"{o.name:28s} {o.status:9s} {o.seconds:6.0f} s  {_failing_count(o):>18s}  {o.caught_by}",
                  flush=True)
            if o.status in ("error", "timeout") and o.output:
                print(o.output, file=sys.stderr)

        outcomes = run_mutations(mutations, full=args.full, timeout=args.timeout, baseline=not args.no_baseline,
                                 keep=args.keep, progress=progress, stop_first=not args.all_failures)
    except MutationError as exc:
        print(f"mutate: {exc}", file=sys.stderr)
        return 2
    table = markdown_table(mutations, outcomes)
    print()
    print(table)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.markdown.with_name(f".{args.markdown.name}.tmp")
        tmp.write_text(table + "\n")
        os.replace(tmp, args.markdown)
    return 0 if all(o.caught for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
