import numpy as np
import pytest

from opalflow.opal.scene import build_opal
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec


@pytest.fixture(scope="session")
def quick_spec():
    return load_spec(WORKFLOWS / "opal_quick.toml")


@pytest.fixture(scope="session")
def quick_structure(quick_spec):
    structure, _ = build_opal(quick_spec)
    return structure


@pytest.fixture(scope="session")
def coated_quick():
    """Quick scene coated with 60 nm (one particle diameter) of titania."""
    spec = load_spec(WORKFLOWS / "opal_quick.toml", ["coating.thickness_nm=60.0"])
    structure, _ = build_opal(spec)
    return spec, structure


def brute_force_pairs(x, r, box, periodic):
    """All pairs closer than r by direct O(N^2) minimum-image distances."""
    d = x[None, :, :] - x[:, None, :]
    for k in range(3):
        if periodic[k]:
            d[..., k] -= box[k] * np.round(d[..., k] / box[k])
    dist = np.sqrt((d**2).sum(-1))
    i, j = np.nonzero(np.triu(dist < r, 1))
    return np.column_stack([i, j])


def assert_refused(capsys, argv: list[str], sets: list[str], field: str, out) -> None:
    """The CLI refuses the --set values with one line naming ``field``, exit 2, ``out`` not created."""
    from opalflow.cli import main

    for s in sets:
        argv = argv + ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith(f"error: {field} = ")
    assert not out.exists()
