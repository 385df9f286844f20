"""Specs of the aerogel track: ``[aggregate]`` (kind ``aggregation``) and the bonded aggregate compressed
between walls (kind ``aerogel``: ``[aggregate]`` plus the compression pipeline's sections)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from opalflow.bpm.methods import METHODS
from opalflow.bpm.spec import BondsSpec, BoundarySpec, BpmWorkflow, CompressionSpec, check_material
from opalflow.spec import WorkflowSpec, check
from opalflow.vocabulary import LOOP_MODELS

ALGORITHMS = ("dlca", "rlca")
#: how the clusters move: one step per move, or free-distance jumps (opalflow.aerogel.aggregation)
STEPPINGS = ("fixed", "jump")
#: the largest neck gap, as a fraction of the contact distance (a neck wider than half a sphere is a rod)
NECK_GAP_MAX = 0.5
#: the normal distribution below zero: at most this fraction of draws may be non-positive
NONPOSITIVE_MAX = 0.01
#: solid fractions above this are placed on a jittered grid (random addition jams near 0.38)
RANDOM_PLACEMENT_MAX = 0.3


@dataclass
class AggregateSpec:
    """Cluster-cluster aggregation in a periodic cube (opalflow.aerogel.aggregation)."""

    particles: int = 3000            # spheres in the periodic aggregation box
    solid_fraction: float = 0.05     # their volume fraction of the box (sets the box and the aerogel's density)
    diameter_nm: float = 10.0        # mean sphere diameter
    diameter_std_nm: float = 1.0     # standard deviation of the diameters
    algorithm: str = "dlca"                  # dlca: every contact sticks; rlca: with sticking_probability
    sticking_probability: float = 1.0  # rlca: the chance that a contact sticks (1: DLCA)
    step_fraction: float = 0.5               # random-walk step of a single sphere, in mean diameters
    mobility_exponent: float = -0.5          # D ~ N^alpha (Meakin 1983)
    stepping: str = "fixed"                  # fixed: a step per move; jump: free-distance jumps (dilute: fast)
    #: none (trees), deflection, restructuring, necks (opalflow/aerogel/loops.py)
    loops: str = "none"
    neck_gap: float = 0.1                    # necks: bond pairs whose gap is below this x (r_i + r_j)
    seed: int = 1                            # random seed of the spheres' positions and walks

    def box_estimate(self) -> tuple[float, float]:
        """Edge of the cube (nm) from the mean sphere volume, and the largest diameter expected (mean + 4 std)."""
        mu, sd = self.diameter_nm, self.diameter_std_nm
        volume = self.particles * math.pi / 6 * (mu**3 + 3 * mu * sd**2)
        return (volume / self.solid_fraction) ** (1 / 3), mu + 4 * sd

    def validate(self) -> None:
        check(2 <= self.particles <= 5_000_000, "aggregate.particles", self.particles, "must be in [2, 5e6]")
        check(0 < self.solid_fraction <= 0.5, "aggregate.solid_fraction", self.solid_fraction, "must be in (0, 0.5]")
        check(1e-3 <= self.diameter_nm <= 1e5, "aggregate.diameter_nm", self.diameter_nm, "must be in [1e-3, 1e5] nm")
        check(self.diameter_std_nm >= 0, "aggregate.diameter_std_nm", self.diameter_std_nm, "must be >= 0")
        z = 2.326                                          # P(d <= 0) = 1 % at mean = 2.326 std
        check(self.diameter_std_nm * z <= self.diameter_nm, "aggregate.diameter_std_nm", self.diameter_std_nm,
              f"must be <= diameter_nm / {z} = {self.diameter_nm / z:.4g} (otherwise more than "
              f"{NONPOSITIVE_MAX:.0%} of the Gaussian draws are non-positive sizes)")
        check(self.algorithm in ALGORITHMS, "aggregate.algorithm", self.algorithm, f"must be one of {', '.join(ALGORITHMS)}")
        check(0 < self.sticking_probability <= 1, "aggregate.sticking_probability", self.sticking_probability,
              "must be in (0, 1]")
        if self.algorithm == "dlca":
            check(self.sticking_probability == 1, "aggregate.sticking_probability", self.sticking_probability,
                  "must be 1 for algorithm = \"dlca\" (every contact sticks); use algorithm = \"rlca\"")
        else:
            check(self.sticking_probability < 1, "aggregate.sticking_probability", self.sticking_probability,
                  "must be < 1 for algorithm = \"rlca\" (1 is DLCA), e.g. 0.01")
        check(0 < self.step_fraction <= 2, "aggregate.step_fraction", self.step_fraction,
              "must be in (0, 2] (mean diameters per step of a single sphere)")
        check(-2 <= self.mobility_exponent <= 0, "aggregate.mobility_exponent", self.mobility_exponent,
              "must be in [-2, 0] (D ~ N^alpha)")
        check(self.stepping in STEPPINGS, "aggregate.stepping", self.stepping, f"must be one of {', '.join(STEPPINGS)}")
        check(self.loops in LOOP_MODELS, "aggregate.loops", self.loops, f"must be one of {', '.join(LOOP_MODELS)}")
        check(0 < self.neck_gap <= NECK_GAP_MAX, "aggregate.neck_gap", self.neck_gap,
              f"must be in (0, {NECK_GAP_MAX}] (the gap a neck bridges, as a fraction of r_i + r_j)")
        check(0 <= self.seed < 2**31, "aggregate.seed", self.seed, "must be in [0, 2^31)")
        box, d_max = self.box_estimate()
        cell = self.step_fraction * self.diameter_nm + d_max
        check(box >= 3 * cell, "aggregate.particles", self.particles,
              f"too few for the box: at solid fraction {self.solid_fraction:g} the cube ({box:.3g} nm) must hold "
              f"3 cells of step + largest diameter ({cell:.3g} nm); use more particles")
        if self.solid_fraction > RANDOM_PLACEMENT_MAX:
            slot = box / math.ceil(self.particles ** (1 / 3))
            check(slot >= d_max, "aggregate.solid_fraction", self.solid_fraction,
                  f"too high for these diameters: above {RANDOM_PLACEMENT_MAX} the spheres start on a grid of "
                  f"{slot:.3g} nm slots, smaller than the largest diameter expected ({d_max:.3g} nm)")


@dataclass
class AggregationWorkflow(WorkflowSpec):
    """One aggregate (kind = "aggregation"): its fractal dimension, pictures and bonded data file."""

    aggregate: AggregateSpec = field(default_factory=AggregateSpec)
    bonds: BondsSpec = field(default_factory=lambda: BondsSpec(cutoff_factor=1.001))
    material: str = "silica"         # the spheres' material (data/materials.toml), for the bonded data file

    def validate(self) -> None:
        super().validate()
        check_material("material", self.material)
        self.aggregate.validate()
        check(1.0 <= self.bonds.cutoff_factor <= 1.1, "bonds.cutoff_factor", self.bonds.cutoff_factor,
              "must be in [1.0, 1.1] (bonds at contacts: centre distance within this factor of the contact distance)")
        check(self.bonds.min_length_factor == 0, "bonds.min_length_factor", self.bonds.min_length_factor,
              "must be 0 for an aggregate (its bonds are its contacts)")


@dataclass
class SampleSpec:
    """What the aerogel workflow loads: the slab cut from the aggregate (compressed on its bottom layer), or
    the periodic cube itself (``periodic_z``: no cut, no walls; the static 6 x 6 stiffness tensor)."""

    periodic_z: bool = False         # load the periodic cube itself (static method: the 6 x 6 tensor) instead of a slab


@dataclass
class AerogelWorkflow(BpmWorkflow):
    """A bonded aggregate (kind = "aerogel") cut to a slab and compressed between a fixed bottom layer and
    a plate; sides periodic.  With ``sample.periodic_z`` the whole periodic cube instead (static tensor)."""

    aggregate: AggregateSpec = field(default_factory=AggregateSpec)
    sample: SampleSpec = field(default_factory=SampleSpec)
    bonds: BondsSpec = field(default_factory=lambda: BondsSpec(cutoff_factor=1.001, length_bins=1))
    boundary: BoundarySpec = field(default_factory=BoundarySpec)
    compression: CompressionSpec = field(default_factory=lambda: CompressionSpec(loading="glued"))

    def validate(self) -> None:
        super().validate()
        self.aggregate.validate()
        check(self.boundary.sides == "periodic", "boundary.sides", self.boundary.sides,
              "must be \"periodic\" (the aggregate is periodic sideways; open sides would cut it free)")
        if self.sample.periodic_z:
            check(METHODS[self.compression.method].tensor, "sample.periodic_z", self.sample.periodic_z,
                  "needs compression.method = \"static\" (the periodic cube has no walls to compress it between)")
        check(1.0 <= self.bonds.cutoff_factor <= 1.1, "bonds.cutoff_factor", self.bonds.cutoff_factor,
              "must be in [1.0, 1.1] (bonds at contacts: centre distance within this factor of the contact distance)")
        check(self.bonds.min_length_factor == 0, "bonds.min_length_factor", self.bonds.min_length_factor,
              "must be 0 for an aggregate (its bonds are its contacts)")
