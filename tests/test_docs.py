"""The README and the reference pages under docs/: short front page, links that resolve, no history in the prose.

- README.md is at most 250 lines and opens (first 15 lines) with a code block holding `make run` and `make test`;
  it carries the results block that `make quality` regenerates.
- Every relative Markdown link or image in README.md and docs/*.md points to an existing file, and so does every
  `docs/...` path quoted as inline code (e.g. a measurement JSON).
- Nothing in the docs, the package, the stages or eval/ refers to tracker issues ("issue 13"), and README/docs
  carry no commit hashes: they say what is true now, and the history lives in git.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOC_PAGES = sorted((REPO / "docs").glob("*.md"))
MARKDOWN = [README, *DOC_PAGES]

README_MAX_LINES = 250
RESULTS_BEGIN = "<!-- results:begin -->"
RESULTS_END = "<!-- results:end -->"

FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.M | re.S)
INLINE_CODE = re.compile(r"`+[^`\n]*`+")
# [text](target) and ![alt](target), with an optional "title"; the text may hold one level of brackets.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)
DOCS_PATH_IN_CODE = re.compile(r"`(docs/[^`\s]+)`")
ISSUE = re.compile(r"issue ?#?[0-9]+", re.I)
URL = re.compile(r"(?:https?|ftp)://\S+|www\.\S+")
# A commit-hash-like token: 7–40 hex digits with at least one digit and one letter a–f, standing alone. A token
# glued to a word by '-', '.', '_' or '/' (a file name such as vgg16-397923af.pth, a path) is not prose.
COMMIT_HASH = re.compile(
    r"(?<![\w./-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w/-]|\.\w)", re.I
)


def _rel(path: Path) -> str:
    return str(path.relative_to(REPO))


def _without_code(text: str) -> str:
    """The Markdown with fenced code blocks and inline code spans blanked out (links in code are not links)."""
    text = FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)
    return INLINE_CODE.sub("", text)


def _link_targets(text: str) -> list[str]:
    prose = _without_code(text)
    return [m.group(1) for m in LINK.finditer(prose)] + [m.group(1) for m in REFERENCE_DEF.finditer(prose)]


def _is_external(target: str) -> bool:
    return bool(re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I)) or target.startswith("//")


def _tree_files(folder: str, suffixes: tuple[str, ...]) -> list[Path]:
    root = REPO / folder
    if not root.is_dir():
        return []
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in suffixes
                  and "__pycache__" not in p.parts and "node_modules" not in p.parts)


# --- README: the front page ---------------------------------------------------------------------------------


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; at most {README_MAX_LINES}"


def test_readme_opens_with_the_two_commands():
    head = "\n".join(README.read_text(encoding="utf-8").splitlines()[:15])
    blocks = [m.group(0) for m in FENCE.finditer(head)]
    assert blocks, "README.md: no complete code block in its first 15 lines"
    assert any("make run" in b and "make test" in b for b in blocks), (
        "README.md: the first code block within 15 lines must hold `make run` and `make test`")


def test_readme_has_one_results_block():
    text = README.read_text(encoding="utf-8")
    assert text.count(RESULTS_BEGIN) == 1 and text.count(RESULTS_END) == 1, (
        f"README.md needs exactly one {RESULTS_BEGIN} … {RESULTS_END} block (make quality rewrites it)")
    block = text[text.index(RESULTS_BEGIN) + len(RESULTS_BEGIN): text.index(RESULTS_END)]
    assert "|" in block, "README.md: the results block holds no table"


def test_the_readme_results_block_is_what_make_quality_writes():
    """The averages under the table are computed from it (eval.bench.experiment.summary), so they follow the table."""
    from eval.bench.experiment import results_block, summary

    text = README.read_text(encoding="utf-8")
    block = text[text.index(RESULTS_BEGIN) + len(RESULTS_BEGIN): text.index(RESULTS_END)].strip()
    table = "\n".join(line for line in block.splitlines() if line.startswith("|"))
    assert block == results_block(table) and summary(table), "README.md: run make quality, or results_block by hand"
    rows = table.splitlines()
    gram = [c.strip() for c in rows[0].split("|")].index("Gram distance ↓")
    fast = next(i for i, r in enumerate(rows) if r.startswith("| starry_night | FAST |"))
    cells = rows[fast].split("|")
    cells[gram] = " 9.999 "  # starry_night FAST's Gram distance above NNFM's
    edited = "\n".join(rows[:fast] + ["|".join(cells)] + rows[fast + 1:])
    assert "at or below NNFM's on 2 of 3 paintings" in summary(edited)
    assert summary(table.replace("content SSIM", "SSIM-free")) == ""

# --- links ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("page", MARKDOWN, ids=_rel)
def test_relative_links_resolve(page: Path):
    broken = []
    for target in _link_targets(page.read_text(encoding="utf-8")):
        if _is_external(target) or target.startswith("#"):
            continue
        path = target.split("#", 1)[0].split("?", 1)[0]
        if path and not (page.parent / path).exists():
            broken.append(target)
    assert not broken, f"{_rel(page)}: links to missing files: {broken}"


@pytest.mark.parametrize("page", MARKDOWN, ids=_rel)
def test_quoted_docs_paths_exist(page: Path):
    """`docs/...` paths quoted as inline code (measurement JSONs, figures) are repository-relative and exist."""
    prose = FENCE.sub("", page.read_text(encoding="utf-8"))
    missing = []
    for m in DOCS_PATH_IN_CODE.finditer(prose):
        path = m.group(1).rstrip(".,;:")
        if any(c in path for c in "<>*{}"):  # a pattern such as docs/measurements/x_<painting>.json
            continue
        if not (REPO / path).exists():
            missing.append(path)
    assert not missing, f"{_rel(page)}: quotes paths that do not exist: {missing}"


def test_the_link_checker_sees_links():
    """Guard the checker itself: links in prose count, links in code do not."""
    text = "see [a](docs/A.md) and ![b](img/b.jpg#x)\n```\n[c](nowhere.md)\n```\n`[d](nowhere.md)`\n"
    assert _link_targets(text) == ["docs/A.md", "img/b.jpg#x"]


# --- no history in the prose ----------------------------------------------------------------------------------


def _issue_scan_files() -> list[Path]:
    files = [README, *DOC_PAGES]
    for folder in ("abcgs", "stages", "eval"):
        files += _tree_files(folder, (".py", ".md", ".yaml"))
    return files


def test_no_issue_numbers():
    hits = []
    for path in _issue_scan_files():
        for no, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            for m in ISSUE.finditer(line):
                hits.append(f"{_rel(path)}:{no}: {m.group(0)!r}")
    assert not hits, f"{len(hits)} references to tracker issues:\n" + "\n".join(hits[:50])


@pytest.mark.parametrize("page", MARKDOWN, ids=_rel)
def test_no_commit_hashes(page: Path):
    hits = []
    for no, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        for m in COMMIT_HASH.finditer(URL.sub(" ", line)):
            hits.append(f"{no}: {m.group(0)}")
    assert not hits, f"{_rel(page)}: commit-hash-like tokens: {hits}"


@pytest.mark.parametrize(
    ("text", "hashes"),
    [
        ("measured at commit 92eabd7 on a Zen 4", ["92eabd7"]),
        ("all digits, 4087441, is a number to this pattern", []),
        ("(7958ec9) and `ccf027a`", ["7958ec9", "ccf027a"]),
        ("e2b4ef0's library", ["e2b4ef0"]),
        ("a full 40-digit one: 1031af3aa1031af3aa1031af3aa1031af3aa1031", ["1031af3aa1031af3aa1031af3aa1031af3aa1031"]),
        ("torchvision's vgg16-397923af.pth, 2852 features, 93832 Gaussians, deadbeef", []),
        ("rasterize_cpu.cpp, abcgs/render/csrc, 1e-12, 3.3e-4, 0.0443, AVX512-BF16, ab_fern", []),
        ("https://github.com/owner/repo/commit/4087441", []),
    ],
)
def test_the_hash_pattern(text: str, hashes: list[str]):
    assert [m.group(0) for m in COMMIT_HASH.finditer(URL.sub(" ", text))] == hashes


# --- the package map in abcgs/__init__.py --------------------------------------------------------------------

def test_the_package_map_names_every_package_and_top_level_module_and_nothing_else():
    """``abcgs/__init__.py``'s docstring names each sub-package and top-level module (``:mod:`abcgs.x```), and every
    name it gives exists."""
    import ast

    doc = ast.get_docstring(ast.parse((REPO / "abcgs" / "__init__.py").read_text(encoding="utf-8"))) or ""
    named = set(re.findall(r":mod:`(abcgs(?:\.\w+)+)`", doc))
    pkg = REPO / "abcgs"
    present = {f"abcgs.{p.name}" for p in pkg.iterdir() if (p / "__init__.py").is_file()}
    present |= {f"abcgs.{p.stem}" for p in pkg.glob("*.py") if not p.name.startswith("_")}
    missing = sorted(present - named)
    absent = sorted(m for m in named if not (pkg.joinpath(*m.split(".")[1:]).with_suffix(".py").is_file()
                                             or (pkg.joinpath(*m.split(".")[1:]) / "__init__.py").is_file()))
    assert not missing, f"abcgs/__init__.py's package map leaves out {missing}"
    assert not absent, f"abcgs/__init__.py's package map names modules that do not exist: {absent}"
