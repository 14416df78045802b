"""The repository is self-contained and its front door is short.

- No tracked file refers to a file outside the repository (a design note, a shared folder, the paper's text) or to a
  repository path that does not exist (a moved script, a renamed page): every relative Markdown link resolves to a
  tracked file or folder, and every path under a project folder named in the text (``demos/beams.py``) exists.
- ``README.md`` has at most 200 lines and starts, after its title and introduction, with the two commands that do
  all the set-up: ``make demo`` and ``make test``.

Fast (reads the files ``git ls-files`` lists); skipped outside a git checkout.
"""

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Files outside the repository that text must not rely on.
OUTSIDE = [
    (re.compile(r"\bDESIGN\.md\b"), "a design note outside the repository (use docs/conventions.md)"),
    (re.compile(r"\bSTYLE\.md\b"), "a style note outside the repository"),
    (re.compile(r"\.\./shared\b"), "a shared folder outside the repository"),
    (re.compile(r"\bshared/paper\b"), "the paper's folder outside the repository"),
    (re.compile(r"(?<![\w.-])paper/[\w.-]"), "the paper's folder outside the repository"),
]
#: Project folders whose paths, when named in text, must exist.
FOLDERS = ("demos", "studies", "tests", "bench", "docs", "meshes", "homogenization", "fenicsfoam")
REPO_PATH = re.compile(r"(?<![\w/.-])((?:" + "|".join(FOLDERS) + r")/[\w./-]*\w\.(?:py|md|toml|csv|json|png|c))\b")
MARKDOWN_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


@cache
def tracked() -> tuple[str, ...]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return tuple(sorted(p for p in out.decode().split("\0") if p))


@cache
def tracked_folders() -> frozenset[str]:
    return frozenset(str(parent) for p in tracked() for parent in Path(p).parents if str(parent) != ".")


def text_files() -> list[tuple[str, str]]:
    files = []
    for name in tracked():
        path = ROOT / name
        if not path.is_file() or path.suffix in (".png", ".h5", ".npy"):
            continue
        data = path.read_bytes()
        if b"\0" in data:
            continue
        try:
            files.append((name, data.decode("utf-8")))
        except UnicodeDecodeError:
            continue
    return files


def exists(target: str) -> bool:
    target = target.rstrip("/")
    return target in tracked() or target in tracked_folders()


def test_no_reference_to_files_outside_the_repository():
    problems = []
    for name, text in text_files():
        if name == "tests/test_repository.py":
            continue  # names the patterns it looks for
        for lineno, line in enumerate(text.splitlines(), 1):
            problems += [f"{name}:{lineno}: {what}: {line.strip()[:100]}"
                         for pattern, what in OUTSIDE if pattern.search(line)]
    assert not problems, "files refer to files outside the repository:\n" + "\n".join(problems)


def test_named_repository_paths_exist():
    problems = []
    for name, text in text_files():
        if name == "tests/test_repository.py" or name.endswith(".csv"):
            continue
        for lineno, line in enumerate(text.splitlines(), 1):
            problems += [f"{name}:{lineno}: {path} is not in the repository"
                         for path in REPO_PATH.findall(line) if not exists(path)]
    assert not problems, "\n".join(problems)


def test_relative_markdown_links_resolve():
    problems = []
    for name, text in text_files():
        markdown = name.endswith(".md")
        for lineno, line in enumerate(text.splitlines(), 1):
            for target in MARKDOWN_LINK.findall(line):
                if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                    continue  # a URL or an anchor in the same page
                if not markdown and not target.startswith("docs/"):
                    continue  # in code, only links into docs/ are links
                path = target.split("#", 1)[0]
                resolved = (Path(name).parent / path) if markdown else Path(path)
                normal = Path(*[p for p in resolved.parts if p != "."])
                parts: list[str] = []
                for part in normal.parts:
                    parts = parts[:-1] if part == ".." else [*parts, part]
                if not parts or not exists("/".join(parts)):
                    problems.append(f"{name}:{lineno}: link ({target}) does not resolve to a tracked file")
    assert not problems, "\n".join(problems)


def test_readme_is_short_and_starts_with_the_two_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; keep it at most 200 (reference belongs in docs/)"
    assert lines[0].startswith("# "), "README.md starts with its title"
    start = next(i for i, line in enumerate(lines) if line.startswith("```"))
    end = next(i for i in range(start + 1, len(lines)) if lines[i].startswith("```"))
    assert not any(line.startswith("## ") for line in lines[:start]), (
        "the two commands come right after the title and introduction, before any section")
    commands = [line.split("#")[0].split() for line in lines[start + 1:end] if line.split("#")[0].strip()]
    assert commands == [["make", "demo"], ["make", "test"]], (
        f"README.md's first code block is {commands}, not `make demo` and `make test`")
