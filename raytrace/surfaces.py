"""Materials that vary over a surface: file materials with textures (glTF 2.0 metallic-roughness,
OBJ/MTL diffuse maps) and the procedural spacecraft materials of the built-in presets (crinkled
MLI foil, solar-cell grids), and the tables the shading kernels evaluate them from
(:mod:`raytrace._texture`).

Rules (docs/shading.md, "Materials"): a component with an ``albedo`` override is a plain
Lambertian surface; one with a file ``surface`` (:class:`SurfaceMaterial`, kind ``"gltf"``) is
shaded from it; otherwise its preset, which for ``gold_mli``, ``silver_mli`` and ``solar_cell``
is procedural (:func:`procedural_surface`) unless the scene turns procedural materials off
(:attr:`raytrace.scene.Scene.procedural_materials`). The radiance cache and the secondary
bounces' lobe sampling take each component's mean material (:func:`mean_material`); the pixels
(centres, sub-samples), the surfaces gather, mirror and lobe rays hit and the path tracer's
vertices take the per-hit one.

Sources
-------
* glTF 2.0 metallic-roughness: the glTF 2.0 specification, §3.9.2 and Appendix B.3
  (https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html): ρ_d = base·(1 − metallic),
  F0 = lerp(0.04, base, metallic), α = roughness²; metallicRoughnessTexture: B metal, G rough;
  colour textures sRGB (IEC 61966-2-1 decoding), data textures linear.
* Solar cells: 40 × 80 mm triple-junction cells (AZUR SPACE 3G30C-Advanced datasheet), laid with
  ~1 mm gaps (ESA ECSS-E-ST-20-08C, photovoltaic assemblies; typical cell spacing 0.8–1.0 mm) and a
  ~1 mm silver-plated busbar/interconnector along one short edge; cells ρ_d from their solar
  absorptance ≈ 0.9 (Gilmore 2002, Appendix A). The cover glass over cells and interconnectors
  keeps the preset's specular lobe (F0 0.04, α 0.08) everywhere; the pattern changes the
  diffuse albedo only: cells the preset's, gaps 0.30 (substrate), the busbar 0.60 (matte
  silver seen through the glass; silver's reflectance ≈ 0.97, Real-Time Rendering 4th ed.,
  Table 9.2, dulled by its plating's texture — a plausible value, not a measured one).
* MLI: the outer layer is crinkled so that it does not touch the layers below (Gilmore 2002,
  ch. 5, "Insulation"; wrinkles of ~1–3 cm); the foil between wrinkles is glossy: GGX α 0.15
  here, the crinkle's normal spread (slope amplitude 0.45, per-axis slope variance
  0.45²·0.2) supplying the rest of the preset's wide lobe: seen from afar, where a pixel
  covers many wrinkles, α² + 2σ² = 0.32², the preset's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import _texture as T

__all__ = ["SurfaceMaterial", "material_tables", "mean_material", "procedural_surface", "srgb_to_linear",
           "decode_normal_map"]

MLI_CRINKLE_M = 0.02  # noise cell of the crinkle [m]
MLI_SLOPE = 0.45  # its slope amplitude
MLI_ALPHA = 0.15  # the foil's own GGX α between wrinkles
SOLAR_GAP_M = 0.001
SOLAR_BUSBAR_M = 0.001
SOLAR_BUSBAR_DIFFUSE = 0.60


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (IEC 61966-2-1)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def decode_normal_map(img: np.ndarray) -> np.ndarray:
    """A tangent-space normal map's texels → signed components. 8-bit maps decode so that byte
    128 is exactly 0 ((b − 128)/127, clipped to [−1, 1]: a flat map (128, 128, 255) is exactly
    (0, 0, 1)); float maps as 2·c − 1."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return np.clip((a.astype(np.float64) - 128.0) / 127.0, -1.0, 1.0)
    return 2.0 * a.astype(np.float64) - 1.0


@dataclass(frozen=True, eq=False)
class SurfaceMaterial:
    """A material that varies over a component's surface.

    Attributes
    ----------
    kind : str
        ``"gltf"`` (metallic-roughness, optionally textured), ``"mli"`` or ``"solar_cell"``.
    base_color : tuple of 3 float
        glTF baseColorFactor, linear RGB [-].
    metallic, roughness : float
        glTF metallicFactor and roughnessFactor (perceptual roughness, α = roughness²) [-].
    normal_scale : float
        glTF normalTexture.scale [-].
    base_texture, mr_texture, normal_texture : numpy.ndarray or None
        (h, w, channels) images, row 0 the image's top: the base colour already linear, the
        metallic-roughness as is (linear, [0, 1]), the normal map decoded
        (:func:`decode_normal_map`).
    corner_uv : numpy.ndarray or None
        (n_faces, 3, 2) UVs of each face's corners (trimesh's convention: origin bottom-left).
    dielectric_f0 : float
        F0 of the non-metal part: 0.04 (glTF), 0 for OBJ/MTL's Lambertian ``Kd`` materials [-].
    """

    kind: str = "gltf"
    base_color: tuple = (1.0, 1.0, 1.0)
    metallic: float = 1.0
    roughness: float = 1.0
    normal_scale: float = 1.0
    base_texture: np.ndarray | None = None
    mr_texture: np.ndarray | None = None
    normal_texture: np.ndarray | None = None
    corner_uv: np.ndarray | None = None
    dielectric_f0: float = 0.04
    seed: int = 0
    name: str = field(default="")

    def __post_init__(self):
        if self.kind not in ("gltf", "mli", "solar_cell"):
            raise ValueError(f"surface kind must be 'gltf', 'mli' or 'solar_cell', got {self.kind!r}")
        if self.has_textures and self.corner_uv is None:
            raise ValueError(f"material {self.name or self.kind}: a texture is set but the mesh has no UVs "
                             f"(TEXCOORD_0 / vt)")
        for what in ("base_texture", "mr_texture", "normal_texture"):
            t = getattr(self, what)
            if t is not None:
                t = np.asarray(t, dtype=np.float32)
                if t.ndim == 2:
                    t = t[:, :, None]
                if t.ndim != 3 or t.shape[2] not in (1, 2, 3, 4) or min(t.shape[:2]) < 1 or not np.isfinite(t).all():
                    raise ValueError(f"material {self.name or self.kind}: {what} must be a finite (h, w, 1–4) image")
                object.__setattr__(self, what, np.ascontiguousarray(t))

    @property
    def has_textures(self) -> bool:
        return any(t is not None for t in (self.base_texture, self.mr_texture, self.normal_texture))

    def texel_mean(self, what: str) -> np.ndarray:
        t = getattr(self, what)
        m = t.reshape(-1, t.shape[2]).mean(axis=0)
        return np.resize(m[:3] if t.shape[2] >= 3 else m[:1], 3) if what == "base_texture" else m


def procedural_surface(preset: str, seed: int = 0) -> SurfaceMaterial | None:
    """The procedural material of a preset name (None: the preset is uniform)."""
    if preset in ("gold_mli", "silver_mli"):
        return SurfaceMaterial("mli", seed=seed, name=preset)
    if preset == "solar_cell":
        return SurfaceMaterial("solar_cell", seed=seed, name=preset)
    return None


def gltf_parameters(base, metallic, roughness, dielectric_f0: float = 0.04):
    """glTF 2.0 metallic-roughness → (ρ_d, F0, α) (Appendix B.3; α clamped to [0.02, 1])."""
    base = np.asarray(base, dtype=np.float64)
    m = float(np.clip(metallic, 0.0, 1.0))
    return (base * (1.0 - m), dielectric_f0 * (1.0 - m) + base * m,
            float(np.clip(roughness ** 2, 0.02, 1.0)))


def mean_material(surface: SurfaceMaterial):
    """(ρ_d, F0, α) of the uniform material standing for a file material where one value per
    component is used (the radiance cache's inter-reflection, secondary lobes): texel means of
    the base colour, metallic and roughness through the glTF conversion."""
    base = np.asarray(surface.base_color, dtype=np.float64)
    metal, rough = surface.metallic, surface.roughness
    if surface.base_texture is not None:
        base = base * surface.texel_mean("base_texture")
    if surface.mr_texture is not None:
        m = surface.texel_mean("mr_texture")
        if len(m) >= 3:
            rough *= float(m[1])
            metal *= float(m[2])
    d, f0, a = gltf_parameters(np.clip(base, 0.0, 1.0), metal, rough, surface.dielectric_f0)
    d = np.minimum(d, 1.0 - f0)
    return tuple(d.tolist()), tuple(f0.tolist()), a


def _principal_frame(v: np.ndarray):
    c = v.mean(axis=0)
    _, _, vt = np.linalg.svd(v - c, full_matrices=False)
    ax1, ax2 = vt[0], vt[1] if len(vt) > 1 else np.array([0.0, 1.0, 0.0])
    lo1 = ((v - c) @ ax1).min()
    lo2 = ((v - c) @ ax2).min()
    return c + lo1 * ax1 + lo2 * ax2, ax1, ax2


def material_tables(components, faces: np.ndarray, vertices: np.ndarray, face_offset: np.ndarray,
                    procedural: bool = True):
    """The kernels' tables (:mod:`raytrace._texture`): (mat_par (C, NPAR), face_uv (F, FACE_COLS)
    or a (1, FACE_COLS) placeholder when every component is uniform, atlas float32) and
    whether any component varies."""
    C = len(components)
    par = np.zeros((C, T.NPAR))
    par[:, T.P_TEX_BASE:T.P_TEX_N + 4:4] = -1.0
    chunks, off = [], 0
    surf = []
    for k, comp in enumerate(components):
        s = getattr(comp, "surface", None)
        if comp.albedo is not None:
            s = None
        elif s is None and procedural:
            s = procedural_surface(comp.material, seed=k)
        surf.append(s)
    if all(s is None for s in surf):
        return par, np.zeros((1, T.FACE_COLS)), np.zeros(1, np.float32), False
    face_uv = np.zeros((len(faces), T.FACE_COLS))
    P = vertices[faces]  # (F, 3, 3)
    face_uv[:, 12:21] = P.reshape(-1, 9)
    for k, (comp, s) in enumerate(zip(components, surf)):
        if s is None:
            continue
        lo, hi = face_offset[k], face_offset[k + 1]
        par[k, T.P_SEED] = s.seed
        if s.kind == "mli":
            par[k, T.P_KIND] = T.K_MLI
            par[k, T.P_SCALE] = MLI_CRINKLE_M
            par[k, T.P_AMP] = MLI_SLOPE
            par[k, T.P_ROUGH] = MLI_ALPHA
        elif s.kind == "solar_cell":
            par[k, T.P_KIND] = T.K_SOLAR
            o, a1, a2 = _principal_frame(np.asarray(comp.mesh.vertices, dtype=np.float64))
            par[k, T.P_ORIGIN:T.P_ORIGIN + 3] = o
            par[k, T.P_AX1:T.P_AX1 + 3] = a1
            par[k, T.P_AX2:T.P_AX2 + 3] = a2
            par[k, T.P_SCALE] = SOLAR_GAP_M
            par[k, T.P_AMP] = SOLAR_BUSBAR_M
            par[k, T.P_BASE:T.P_BASE + 3] = T.GAP_DIFFUSE
            par[k, T.P_EXTRA] = SOLAR_BUSBAR_DIFFUSE
        else:
            par[k, T.P_KIND] = T.K_GLTF
            par[k, T.P_BASE:T.P_BASE + 3] = s.base_color
            par[k, T.P_METAL] = s.metallic
            par[k, T.P_ROUGH] = s.roughness
            par[k, T.P_NSCALE] = s.normal_scale
            par[k, T.P_EXTRA] = s.dielectric_f0
            for col, tex in ((T.P_TEX_BASE, s.base_texture), (T.P_TEX_MR, s.mr_texture),
                             (T.P_TEX_N, s.normal_texture)):
                if tex is not None:
                    h, w, ch = tex.shape
                    par[k, col:col + 4] = (off, w, h, ch)
                    chunks.append(tex.ravel())
                    off += tex.size
            if s.corner_uv is not None:
                uv = np.asarray(s.corner_uv, dtype=np.float64)
                face_uv[lo:hi, 0:6] = uv.reshape(-1, 6)
                e1 = P[lo:hi, 1] - P[lo:hi, 0]
                e2 = P[lo:hi, 2] - P[lo:hi, 0]
                du1, dv1 = uv[:, 1, 0] - uv[:, 0, 0], uv[:, 1, 1] - uv[:, 0, 1]
                du2, dv2 = uv[:, 2, 0] - uv[:, 0, 0], uv[:, 2, 1] - uv[:, 0, 1]
                det = du1 * dv2 - du2 * dv1
                ok = np.abs(det) > 1e-20
                inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
                face_uv[lo:hi, 6:9] = (e1 * dv2[:, None] - e2 * dv1[:, None]) * inv  # dP/du
                face_uv[lo:hi, 9:12] = (e2 * du1[:, None] - e1 * du2[:, None]) * inv  # dP/dv
    atlas = np.concatenate(chunks).astype(np.float32) if chunks else np.zeros(1, np.float32)
    return par, np.ascontiguousarray(face_uv), atlas, True


def point_materials(scene, s: dict, O, px_rad: float = 0.0) -> None:
    """Where some component's material varies over its surface (:mod:`raytrace.surfaces`): the
    points' own materials into ``s`` (``m_diff``, ``m_f0``, ``m_alpha``) and their shading
    normals ``NS`` perturbed (normal maps, MLI crinkle); ``px_rad`` the angle a pixel spans
    (the procedural patterns are box-filtered over its footprint, |P − O|·px_rad; 0: not
    filtered; < 0: their mean, :func:`raytrace._texture.material_at`). Nothing where every
    material is uniform: the kernels then read the components' rows."""
    mat_par, face_uv, atlas, varying = scene.material_tables
    if not varying:
        return
    n = len(s["face"])
    mats = scene.materials
    diff = np.array([m.diffuse for m in mats], dtype=np.float64)
    f0 = np.array([m.f0 for m in mats], dtype=np.float64)
    alpha = np.array([m.roughness for m in mats], dtype=np.float64)
    if px_rad > 0.0:
        foot = np.linalg.norm(s["P"] - np.asarray(O).reshape(-1, 3), axis=1) * px_rad
    else:
        foot = np.full(n, -1.0 if px_rad < 0.0 else 0.0)
    s["m_diff"] = np.empty((n, 3))
    s["m_f0"] = np.empty((n, 3))
    s["m_alpha"] = np.empty(n)
    T.eval_hits(np.ascontiguousarray(s["face"], dtype=np.int64), s["comp"], s["B"], s["NS"], s["WO"], foot, diff, f0,
                alpha, mat_par, face_uv, atlas, s["m_diff"], s["m_f0"], s["m_alpha"])


def _image(img, mode: str) -> np.ndarray:
    return np.asarray(img.convert(mode) if hasattr(img, "convert") else img)


def file_texture_names(path, file_type: str) -> dict:
    """{material name: {trimesh attribute: texture}} of the textures a glTF/GLB or OBJ file's
    materials name (OBJ: the MTL libraries in its folder), to tell a texture trimesh could not
    read (it drops those silently) from none at all; {} for other formats or files it cannot
    parse (trimesh's own errors then speak)."""
    import json
    import struct
    from pathlib import Path
    p = Path(path)
    out: dict = {}
    try:
        if file_type == "obj":
            libs = [line.split(None, 1)[1].strip() for line in p.read_text(errors="replace").splitlines()
                    if line.startswith("mtllib ") and len(line.split(None, 1)) > 1]
            for lib in libs:
                current = None
                for line in (p.parent / lib).read_text(errors="replace").splitlines():
                    words = line.strip().split()
                    if len(words) >= 2 and words[0] == "newmtl":
                        current = words[1]
                    elif len(words) >= 2 and words[0] == "map_Kd" and current is not None:
                        out.setdefault(current, {})["image"] = words[-1]
            return out
        if file_type == "glb":
            raw = p.read_bytes()
            n = struct.unpack_from("<I", raw, 12)[0]
            doc = json.loads(raw[20:20 + n])
        elif file_type == "gltf":
            doc = json.loads(p.read_text())
        else:
            return out
        images = doc.get("images", [])
        textures = doc.get("textures", [])

        def what(ref):
            src = textures[ref["index"]].get("source") if ref["index"] < len(textures) else None
            uri = images[src].get("uri", "embedded") if src is not None and src < len(images) else "embedded"
            return uri if not uri.startswith("data:") else "an embedded image"

        for m in doc.get("materials", []):
            pbr = m.get("pbrMetallicRoughness", {})
            slots = {"baseColorTexture": pbr.get("baseColorTexture"),
                     "metallicRoughnessTexture": pbr.get("metallicRoughnessTexture"),
                     "normalTexture": m.get("normalTexture")}
            named = {k: what(v) for k, v in slots.items() if isinstance(v, dict) and "index" in v}
            if named and m.get("name"):
                out[m["name"]] = named
    except (OSError, ValueError, KeyError, IndexError, TypeError, struct.error):
        return {}
    return out


def surface_from_visual(visual, corner_vertex: np.ndarray, where: str, file_textures: dict | None = None):
    """A file part's textured material as a :class:`SurfaceMaterial` (None: the part has no
    texture, and the presets' rules apply): glTF's ``PBRMaterial`` (baseColorFactor and
    texture, metallic/roughness factors and texture, normal texture; TEXCOORD_0) or OBJ/MTL's
    ``SimpleMaterial`` (``Kd``, ``map_Kd``: Lambertian). ``corner_vertex`` (n_faces, 3): the
    file's vertex of each kept corner. ``where`` names the part in messages; ``file_textures``
    (:func:`file_texture_names`) lets a texture trimesh could not read raise instead of
    vanishing."""
    from trimesh.visual.material import PBRMaterial, SimpleMaterial
    mat = getattr(visual, "material", None)
    uv = getattr(visual, "uv", None)
    mname = getattr(mat, "name", None)
    for attr, name in (file_textures or {}).get(mname, {}).items():
        if getattr(mat, attr, None) is None:
            raise ValueError(f"{where}: texture {name!r} of material {mname!r} cannot be read "
                             f"(missing or not an image)")
    if isinstance(mat, PBRMaterial):
        base, mr, nrm = mat.baseColorTexture, mat.metallicRoughnessTexture, mat.normalTexture
        if base is None and mr is None and nrm is None:
            return None
        f = np.asarray(mat.baseColorFactor if mat.baseColorFactor is not None else [255, 255, 255, 255], float)
        f = f / 255.0 if f.max() > 1.0 or np.asarray(mat.baseColorFactor).dtype == np.uint8 else f
        kw = dict(base_color=tuple(np.clip(f[:3], 0.0, 1.0).tolist()),
                  metallic=1.0 if mat.metallicFactor is None else float(mat.metallicFactor),
                  roughness=1.0 if mat.roughnessFactor is None else float(mat.roughnessFactor),
                  base_texture=None if base is None else srgb_to_linear(_image(base, "RGB") / 255.0),
                  mr_texture=None if mr is None else _image(mr, "RGB") / 255.0,
                  normal_texture=None if nrm is None else decode_normal_map(_image(nrm, "RGB")))
    elif isinstance(mat, SimpleMaterial):
        if getattr(mat, "image", None) is None:
            return None
        kd = np.asarray(mat.diffuse if mat.diffuse is not None else [255, 255, 255, 255], float)[:3] / 255.0
        kw = dict(base_color=tuple(kd.tolist()), metallic=0.0, roughness=1.0, dielectric_f0=0.0,
                  base_texture=srgb_to_linear(_image(mat.image, "RGB") / 255.0))
    else:
        return None
    if uv is None or len(uv) <= int(np.max(corner_vertex)):
        raise ValueError(f"{where}: material {mname!r} has a texture but the part has no texture "
                         f"coordinates (glTF TEXCOORD_0, OBJ vt)")
    corner_uv = np.asarray(uv, dtype=np.float64)[corner_vertex]
    if not np.isfinite(corner_uv).all():
        raise ValueError(f"{where}: material {mname!r}: texture coordinates must be finite")
    return SurfaceMaterial("gltf", corner_uv=corner_uv, name=str(mname or ""), **kw)
