"""The documentation builds with warnings as errors, and its Python examples run.

Both builds run ``sphinx-build`` in a subprocess, as a user would, into pytest's temporary
folder (never ``docs/_build``), sharing one doctree folder so that the second build reads
the sources once. Skipped only where Sphinx itself is not installed (the ``docs`` extra).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip(
    "sphinx", reason="Sphinx is not installed: pip install -e '.[docs]' to build the docs"
)

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


@pytest.fixture(scope="module")
def doctrees(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("doctrees")


def _sphinx(builder: str, out: Path, doctrees: Path, *options: str) -> str:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-b",
            builder,
            "-d",
            str(doctrees),
            *options,
            str(DOCS),
            str(out),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"sphinx-build -b {builder} failed:\n{output[-6000:]}"
    return output


@pytest.mark.slow  # 90 s on 2 cores; the examples' build below reads every page too
def test_the_docs_build_with_warnings_as_errors(tmp_path, doctrees):
    _sphinx("html", tmp_path / "html", doctrees, "-W", "--keep-going", "-q")
    html = tmp_path / "html"
    for page in ("index", "commands", "cmetric", "pipeline", "reference/config", "notes/index"):
        assert (html / f"{page}.html").is_file(), page
    # the configuration reference is generated from the schemas: a field of each kind
    reference = (html / "reference/config.html").read_text(encoding="utf-8")
    for field in ("mix_sampling", "degree_rule", "vehicles_density", "ego_speeds"):
        assert field in reference, field


def test_the_docs_examples_run(tmp_path, doctrees):
    output = _sphinx("doctest", tmp_path / "doctest", doctrees, "-W", "--keep-going")
    summary = (tmp_path / "doctest" / "output.txt").read_text(encoding="utf-8")
    assert "0 failures in tests" in summary, output[-6000:]
    assert " 0 tests" not in summary.split("Doctest summary")[-1], summary
