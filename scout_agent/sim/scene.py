"""The MuJoCo scene: a terrain heightfield, the Aliengo, lunar gravity and the contact settings that matter.

Settings (docs/physics.md, "The world"): dt 0.002 s, elliptic friction cone, impratio 10, implicitfast integrator (the joint
PD servos' damping is then integrated implicitly), ground friction 0.7 (feet have priority; their friction
comes from the friction map).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from scout_agent.robot.constants import LUNAR_G
from scout_agent.robot.model import build_aliengo_spec
from scout_agent.sim.friction import DEFAULT_MU
from scout_agent.sim.terrain import Terrain

TERRAIN_GEOM = "terrain"


@dataclass(frozen=True)
class PhysicsConfig:
    timestep: float = 0.002  # [s]
    gravity: float = LUNAR_G  # [m/s²]
    impratio: float = 10.0
    ground_mu: float = DEFAULT_MU
    # the ground goes on beyond the generated field: its edge heights carried this far outward [m] (what
    # `Terrain.height` answers there too). A scout placed a few metres wrong near the field's edge walked off a
    # cliff into the void before (100 m seed 33 with `--localize off`, true x 100.1); the Moon has no such edge.
    skirt_m: float = 5.0


def build_scene(terrain: Terrain, physics: PhysicsConfig = PhysicsConfig()) -> mujoco.MjModel:
    spec = build_aliengo_spec()
    spec.option.timestep = physics.timestep
    spec.option.gravity = [0.0, 0.0, -physics.gravity]
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = physics.impratio
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    if not physics.skirt_m >= 0.0:
        raise ValueError(f"skirt_m {physics.skirt_m!r}: valid: a width >= 0 [m]")
    pad = int(np.ceil(physics.skirt_m / terrain.res))
    z = np.pad(
        terrain.z, pad, mode="edge"
    )  # the same cell spacing: the field's vertices stay where they were
    ny, nx = z.shape
    zmin, zmax = float(z.min()), float(z.max())
    zrange = max(zmax - zmin, 1e-3)
    xa, ya, xb, yb = terrain.extent
    xa, ya, xb, yb = (
        xa - pad * terrain.res,
        ya - pad * terrain.res,
        xb + pad * terrain.res,
        yb + pad * terrain.res,
    )
    spec.add_hfield(
        name=TERRAIN_GEOM,
        size=[(xb - xa) / 2, (yb - ya) / 2, zrange, 0.2],
        nrow=ny,
        ncol=nx,
        userdata=((z - zmin) / zrange).astype(np.float32).ravel(),  # an array: a list of 16 M floats is ~1 GB
    )
    spec.worldbody.add_geom(
        name=TERRAIN_GEOM,
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname=TERRAIN_GEOM,
        pos=[(xa + xb) / 2, (ya + yb) / 2, zmin],
        friction=[physics.ground_mu, 0.005, 1e-4],
        rgba=[0.55, 0.55, 0.52, 1.0],
        condim=3,
    )
    spec.worldbody.add_light(pos=[(xa + xb) / 2, (ya + yb) / 2, zmax + 10], dir=[0, 0, -1])
    return spec.compile()
