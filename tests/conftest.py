from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GRID = ROOT / "experiments" / "duration_interval_grid.yaml"


@pytest.fixture
def grid_path() -> Path:
    return GRID


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``python -m vtexp ARGS`` as a user would, capturing both streams."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "vtexp", *args], cwd=cwd or ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def cli():
    return run_cli


def write_experiment(tmp_path: Path, text: str, name: str = "exp.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


MINIMAL = """\
name: mini
title: A minimal experiment
device: vest_6x8
stimuli:
  square: {generator: shape, params: {shape: square}}
  circle: {generator: shape, params: {shape: circle}}
encoding:
  pipeline: edge-trace
coding:
  protocol: sequential-trace
  params: {duration_ms: 200, soa_ms: 200}
factors:
  shape:
    sets: stimulus
    levels: [square, circle]
design:
  repetitions: 2
  iti_ms: 0
question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"
"""


@pytest.fixture
def minimal_yaml() -> str:
    return MINIMAL
