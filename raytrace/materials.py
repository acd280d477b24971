"""BRDF presets of the target materials: Lambertian diffuse plus a GGX specular lobe.

Every material is ``f(ω_i, ω_o) = ρ_d/π + D·G₂·F / (4 cosθ_i cosθ_o)`` (:mod:`raytrace.brdf`)
with three parameters: the diffuse albedo ``ρ_d`` (linear RGB), the specular reflectance at
normal incidence ``F0`` (linear RGB, Schlick's Fresnel) and the GGX roughness ``α``
(Walter et al. 2007, with α the width parameter, not the artist's "roughness" whose square
it often is).

Values and their sources
------------------------
* Metals' F0 (aluminium, gold, silver, titanium): Real-Time Rendering 4th ed., Table 9.2
  (linear RGB F0 from measured spectral indices): Al (0.912, 0.914, 0.920), Au (1.000, 0.766,
  0.336), Ag (0.972, 0.960, 0.915), Ti (0.542, 0.497, 0.449).
* Dielectrics (paints, cover glass): F0 = 0.04 (n ≈ 1.5).
* Thermal-control surfaces from their solar absorptance α_s (reflectance ≈ 1 − α_s):
  white paint (Z-93 / S13G-LO, α_s ≈ 0.15–0.20) → ρ_d 0.80; black paint (Z-306, α_s ≈ 0.95)
  → 0.05; solar cells (α_s ≈ 0.9, dark blue) → ρ_d (0.02, 0.03, 0.08) behind glossy cover
  glass. Gilmore, *Spacecraft Thermal Control Handbook* Vol. I (2002), Appendix A.
* MLI foil is crinkled: its specular lobe is wide (α 0.3–0.35) rather than a mirror. Gold MLI
  is aluminised Kapton seen through the Kapton (amber, F0 tinted like gold, a little lower);
  silver MLI is aluminised Kapton/Mylar seen from the metal side.
These are plausible presets, not measured BRDFs of a given spacecraft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import MATERIALS

__all__ = ["MATERIAL_PRESETS", "Material", "lambertian", "material_of"]


@dataclass(frozen=True, slots=True)
class Material:
    """A BRDF: Lambertian ``diffuse`` plus GGX specular with ``f0`` and ``roughness``.

    Attributes
    ----------
    name : str
    diffuse : tuple of 3 float
        Diffuse albedo ρ_d, linear RGB in [0, 1] [-].
    f0 : tuple of 3 float
        Specular reflectance at normal incidence, linear RGB in [0, 1] [-].
    roughness : float
        GGX width α in [0.02, 1] (ignored when ``f0`` is zero) [-].
    """

    name: str
    diffuse: tuple
    f0: tuple = (0.0, 0.0, 0.0)
    roughness: float = 1.0

    def __post_init__(self):
        for field in ("diffuse", "f0"):
            v = tuple(float(x) for x in getattr(self, field))
            if len(v) != 3 or not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in v):
                raise ValueError(f"material {self.name}: {field} must be 3 numbers in [0, 1], got {v}")
            object.__setattr__(self, field, v)
        if not (math.isfinite(self.roughness) and 0.02 <= self.roughness <= 1.0):
            raise ValueError(f"material {self.name}: roughness must be in [0.02, 1], got {self.roughness!r}")
        if any(d + f > 1.0 + 1e-9 for d, f in zip(self.diffuse, self.f0)):
            raise ValueError(f"material {self.name}: diffuse + f0 must not exceed 1 per channel "
                             f"(energy), got {self.diffuse} + {self.f0}")

    @property
    def is_lambertian(self) -> bool:
        return max(self.f0) == 0.0


MATERIAL_PRESETS = {
    "gold_mli": Material("gold_mli", (0.04, 0.025, 0.005), (0.85, 0.60, 0.22), 0.32),
    "silver_mli": Material("silver_mli", (0.05, 0.05, 0.05), (0.88, 0.87, 0.83), 0.30),
    "white_paint": Material("white_paint", (0.80, 0.80, 0.78), (0.04, 0.04, 0.04), 0.50),
    "black_paint": Material("black_paint", (0.05, 0.05, 0.05), (0.04, 0.04, 0.04), 0.60),
    "solar_cell": Material("solar_cell", (0.02, 0.03, 0.08), (0.04, 0.04, 0.04), 0.08),
    "aluminium": Material("aluminium", (0.0, 0.0, 0.0), (0.912, 0.914, 0.920), 0.35),
    "black_radiator": Material("black_radiator", (0.06, 0.06, 0.06), (0.04, 0.04, 0.04), 0.50),
    "dish": Material("dish", (0.75, 0.75, 0.73), (0.04, 0.04, 0.04), 0.60),
    "heat_shield": Material("heat_shield", (0.10, 0.09, 0.08), (0.04, 0.04, 0.04), 0.85),
    "titanium": Material("titanium", (0.0, 0.0, 0.0), (0.542, 0.497, 0.449), 0.40),
}
"""One preset per name in :data:`raytrace.model.MATERIALS`."""

assert set(MATERIAL_PRESETS) == set(MATERIALS), "every material name needs a BRDF preset"


def lambertian(albedo, name: str = "lambertian") -> Material:
    """A pure Lambertian material with linear RGB ``albedo`` (a number means grey)."""
    a = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (3,))
    return Material(name, tuple(a.tolist()))


def material_of(component) -> Material:
    """The BRDF of a :class:`~raytrace.model.Component`: its ``albedo`` override (pure
    Lambertian) when set, else the mean of its file material when it has one
    (:func:`raytrace.surfaces.mean_material`; the per-hit values come from
    :mod:`raytrace._texture`), else its material's preset."""
    if component.albedo is not None:
        return lambertian(component.albedo, f"{component.name}_albedo")
    if getattr(component, "surface", None) is not None and component.surface.kind == "gltf":
        from .surfaces import mean_material
        return Material(f"{component.name}_file", *mean_material(component.surface))
    return MATERIAL_PRESETS[component.material]
