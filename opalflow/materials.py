"""Materials: properties from ``data/materials.toml`` (with their sources)."""
from __future__ import annotations

import tomllib
from functools import lru_cache

from opalflow.resources import DATA, resource


@lru_cache(maxsize=1)
def load_materials() -> dict[str, dict]:
    return tomllib.loads(resource(DATA, "materials.toml").read_text())


def material_names() -> tuple[str, ...]:
    return tuple(load_materials())


def material(name: str) -> dict:
    try:
        return load_materials()[name]
    except KeyError:
        raise KeyError(f"unknown material {name!r}; known: {', '.join(material_names())}") from None
