"""Unit conversion, in one place.

Interfaces (TOML, summary keys) are SI with the unit in the name; BPM decks use
LAMMPS ``units nano`` (nm, ns, attogram, pN, MPa for pressure, ag/nm^3 density).
"""
NM_PER_UM = 1.0e3
NM3_PER_UM3 = 1.0e9
#: kg/m^3 per attogram/nm^3 (1 kg/m^3 = 1e21 ag / 1e27 nm^3 = 1e-6 ag/nm^3)
KG_PER_M3_PER_AG_PER_NM3 = 1.0e6


def density_to_nano(rho_kg_m3):
    """Density kg/m^3 -> LAMMPS nano units (attogram/nm^3)."""
    return rho_kg_m3 / KG_PER_M3_PER_AG_PER_NM3  # division: 1297 -> 0.001297 exactly


def density_from_nano(rho_ag_nm3):
    """Density attogram/nm^3 -> kg/m^3."""
    return rho_ag_nm3 * KG_PER_M3_PER_AG_PER_NM3
