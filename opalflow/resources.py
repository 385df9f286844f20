"""Where the project's data, templates and workflows live.

opalflow is installed in editable mode from its repository (``pip install -e .``);
the folders ``data/``, ``templates/`` and ``workflows/`` sit beside the package.
"""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data"
TEMPLATES = ROOT / "templates"
WORKFLOWS = ROOT / "workflows"


def resource(folder: Path, name: str) -> Path:
    path = folder / name
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: install opalflow from its repository "
                                "with 'pip install -e .'")
    return path
