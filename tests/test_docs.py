"""The documentation site's examples run, so they cannot rot: every Python block of docs/*.md is executed,
every `pcreg` command line in its sh blocks must parse with the real argument parser, the API reference
names exactly the public API, and every relative link of the README and the docs reaches a file and a
heading that exist. (`make docs` builds the site itself with mkdocs --strict.)"""

import re
import shlex
from pathlib import Path

import pytest

import pcreg
from pcreg.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = sorted(p for p in DOCS.rglob("*.md"))


def blocks(path: Path, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", path.read_text(), re.S)


def python_blocks():
    return [pytest.param(p, i, code, id=f"{p.relative_to(DOCS)}:{i}")
            for p in PAGES for i, code in enumerate(blocks(p, "python"))]


def command_lines():
    out = []
    for p in PAGES:
        for block in blocks(p, "(?:sh|bash)"):  # the cmd: and CI recipes are bash blocks
            for line in block.splitlines():
                line = line.split("#", 1)[0].split(" > ", 1)[0].strip()  # the shell's redirection is not pcreg's
                if line.startswith("pcreg "):
                    out.append(pytest.param(line, id=f"{p.relative_to(DOCS)}: {line[:60]}"))
    return out


@pytest.mark.parametrize("path, index, code", python_blocks())
def test_python_blocks_run(path, index, code):
    """The examples use built-in synthetic data, so they run in every clone."""
    exec(compile(code, f"{path.name} block {index}", "exec"), {"__name__": "docs"})


@pytest.mark.parametrize("line", command_lines())
def test_command_lines_parse(line):
    build_parser().parse_args(shlex.split(line)[1:])  # exits with code 2 on a bad option


def test_api_reference_names_the_public_api():
    text = (DOCS / "api" / "index.md").read_text()
    documented = set(re.findall(r"^::: pcreg\.(\w+)$", text, re.M))
    assert documented == set(pcreg.__all__)


def slug(heading: str) -> str:
    """The anchor GitHub and mkdocs (toc) give a heading: lower case, punctuation dropped, spaces to '-'."""
    heading = re.sub(r"\{[^}]*\}\s*$", "", heading).strip().lower()
    heading = re.sub(r"[^\w\- ]", "", heading)
    return heading.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    out = {slug(h) for h in re.findall(r"^#+ (.*)$", text, re.M)}
    out |= set(re.findall(r"\{ ?#([\w-]+) ?\}", text))
    return out


@pytest.mark.parametrize("page", [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *PAGES],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"^[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (page.parent / file).resolve() if file else page
        assert dest.exists(), f"{page.name}: {target} does not exist"
        if anchor and dest.suffix == ".md":
            assert anchor in anchors(dest), f"{page.name}: no heading for #{anchor} in {dest.name}"
