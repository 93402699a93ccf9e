"""The README's examples run, so they cannot rot: its Python block is executed, its `pcreg register`
and `pcreg crosscheck` lines run for real (on CamVid frames and the scan pair), and every other `pcreg`
command line in it must parse with the real argument parser."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from pcreg.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def sh_lines(lang: str = "sh"):
    out = []
    for block in re.findall(rf"```{lang}\n(.*?)```", README, re.S):
        for line in block.splitlines():
            line = line.split("#", 1)[0].strip()
            if line.startswith("pcreg "):
                out.append(line)
    return out


def test_readme_has_the_two_commands():
    assert "make demo" in README and "make test" in README


def test_python_example_runs():
    """The example uses built-in synthetic data, so it runs in every clone."""
    code = re.findall(r"```python\n(.*?)```", README, re.S)
    assert code, "README has no python example"
    for block in code:
        exec(compile(block, "README.md", "exec"), {"__name__": "readme"})


@pytest.mark.slow
@pytest.mark.parametrize("line", [l for l in sh_lines() if l.split()[1] in ("register", "crosscheck")])
def test_registration_commands_run(line, shared_data, tmp_path):
    frames = sorted((shared_data / "camvid" / "0016E5" / "images").glob("*.png"))
    line = line.replace("REFERENCE.png", str(frames[0])).replace("MOVING.png", str(frames[2]))
    line = line.replace("../shared/data", str(shared_data))
    args = shlex.split(line)[1:]
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", *args], capture_output=True, text=True, cwd=tmp_path,
                       timeout=300)
    assert p.returncode == 0, p.stderr


@pytest.mark.parametrize("line", [l for l in sh_lines() if l.split()[1] not in ("register", "crosscheck")])
def test_other_commands_parse(line):
    args = shlex.split(line)[1:]
    build_parser().parse_args(args)  # exits with code 2 on a bad option


@pytest.mark.parametrize("line", sh_lines("bash"))
def test_bash_recipes_parse(line):
    """The bash block (a user's own ICP over cmd: and py:) runs on files the user makes: its lines parse."""
    build_parser().parse_args(shlex.split(line)[1:])
