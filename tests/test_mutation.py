"""The mutation harness (tests/mutation/mutate.py, ``make mutate``): every curated bug still applies to the code as
written, a pattern that does not apply fails loudly, and on a tiny target the harness reports a known bug as caught
and a no-op as survived. The curated mutations themselves are run by ``make mutate``, not here."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HERE = ROOT / "tests" / "mutation"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


mutate = _load("mutate")
mutants = _load("mutants")

TARGET = ("tests/test_tensors.py::test_compliance_closed_form",)
#: A wrong Voigt shear factor in the TI compliance: the closed-form test must fail.
KNOWN = mutate.Mutation("s66-factor", "homogenization/tensors.py", "S[5, 5] = 2.0 * (1.0 + nu_t) / E_t",
                        "S[5, 5] = (1.0 + nu_t) / E_t", "S66 = 1/(2 G12)", targets=TARGET)
#: A change of wording in a docstring: no test can fail.
NO_OP = mutate.Mutation("docstring", "homogenization/tensors.py", "the closed form of docs/conventions.md",
                        "the closed-form one of docs/conventions.md", "a docstring reworded", targets=TARGET)


def test_every_curated_mutation_applies_to_the_code_as_written():
    """A refactoring that moves mutated code fails here: update tests/mutation/mutants.py with it."""
    assert len(mutants.MUTATIONS) >= 20
    mutate.check_patterns(mutants.MUTATIONS, ROOT)
    assert all(m.targets or m.mpi_targets for m in mutants.MUTATIONS)


def test_a_pattern_that_does_not_apply_fails_loudly(tmp_path):
    missing = mutate.Mutation("missing", "homogenization/tensors.py", "S[5, 5] = 3.0 *", "x", "none", targets=TARGET)
    twice = mutate.Mutation("twice", "homogenization/tensors.py", "S[", "x", "none", targets=TARGET)
    for bad, message in ((missing, "occurs 0 times"), (twice, r"occurs \d+ times")):
        with pytest.raises(mutate.MutationError, match=message):
            mutate.check_patterns([bad], ROOT)
    copy = mutate.copy_repository(tmp_path / "repo", ROOT, ["homogenization/tensors.py"])
    with pytest.raises(mutate.MutationError, match="occurs 0 times in homogenization/tensors.py"):
        missing.apply(copy)
    with pytest.raises(mutate.MutationError, match="no targets"):
        mutate.Mutation("untargeted", "homogenization/tensors.py", "a", "b", "none")


def test_a_known_bug_is_caught_and_a_no_op_survives():
    outcomes = mutate.run_mutations([KNOWN, NO_OP], timeout=600)
    assert [(o.name, o.status) for o in outcomes] == [("s66-factor", "caught"), ("docstring", "survived")]
    assert outcomes[0].caught_by == TARGET[0]
    table = mutate.markdown_table([KNOWN, NO_OP], outcomes)
    assert "| `s66-factor` |" in table and "**caught**" in table and "**survived**" in table
    assert "1 of 2 mutations caught." in table


def test_every_failing_test_is_listed_without_stopping_at_the_first():
    """The KNOWN bug breaks the closed-form compliance test only: one failure of one test, not stopped at it."""
    (outcome,) = mutate.run_mutations([KNOWN], timeout=600, baseline=False, stop_first=False)
    assert outcome.caught and not outcome.stopped_at_first
    assert outcome.failed == [TARGET[0]] and outcome.collected == 1
    table = mutate.markdown_table([KNOWN], [outcome])
    assert "| 1 / 1 |" in table


def test_pytest_summaries_are_parsed():
    output = ("unit/a.py::t1 FAILED\n=== short test summary info ===\nFAILED unit/a.py::t1 - assert 1 == 2\n"
              "ERROR unit/b.py::t2 - RuntimeError\nFAILED unit/a.py::t1 - again\n"
              "=== 2 failed, 40 passed, 3 skipped, 1 error in 12.5s ===\n")
    assert mutate._failures(output + "FAILED tes\n") == ["unit/a.py::t1", "unit/b.py::t2"]  # interleaved ranks
    mpi = "FAILED unit/a.py::t_long[1]\nFAILED unit/a.py::t_lo\nFAILED unit/a.py::t_long[1]\n"
    assert mutate._failures(mpi, mpi=True) == ["unit/a.py::t_long[1]"]
    assert mutate._grouped(["a.py::t[1]", "a.py::t[2]", "a.py::u"]) == ["`a.py::t` × 2", "`a.py::u`"]
    assert mutate._collected(output) == 46
    assert mutate._collected("killed before the end") is None
    assert mutate._first_failure("unit/c.py::t3 FAILED [ 50%]\n") == "unit/c.py::t3"
