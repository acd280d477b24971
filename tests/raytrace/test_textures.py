"""Materials that vary over a surface: textures from real glTF and OBJ files, the glTF 2.0
metallic-roughness conversion, normal maps, the procedural MLI and solar-cell materials.

Oracles: the files are written here byte by byte (glTF JSON with data URIs, OBJ/MTL text, PNG
images through Pillow) with each format's own UV origin (glTF top-left, OBJ bottom-left); the
expected radiance of a Lambertian quad under the Sun, ρ(u, v)/π·E·cosθ, is computed here from
the pixel's ray–quad intersection, an independent bilinear lookup of the texels written and
the sRGB decoding of IEC 61966-2-1; the glTF conversion from the spec's formulas (Appendix
B.3) through a uniform material; ``balanced`` against the converged path tracer (two seeds,
their noise removed in quadrature as in test_presets_vs_reference.py).
"""

from __future__ import annotations

import base64
import io
import json
import math

import numpy as np
import pytest
import trimesh
from PIL import Image

from raytrace.camera import Camera
from raytrace.lighting import Lighting
from raytrace.materials import Material
from raytrace.meshio import load_mesh
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render
from raytrace.surfaces import SurfaceMaterial

W, H = 64, 48
CAM = Camera(W, H, 40.0, 40.0, (W - 1) / 2, (H - 1) / 2)
R = np.diag([1.0, -1.0, -1.0])  # looking down the body's −z: body +x right, +y up in the image
T = np.array([0.0, 0.0, 1.2])
SUN = np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93])
LIGHT = Lighting(sun_dir_body=tuple(SUN), earth=None, ambient_radiance_W_m2_sr=0.0)
V = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
F = np.array([[0, 1, 2], [0, 2, 3]])
N_TEX = 8


def _srgb_decode(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _srgb_encode(x):
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _pattern_linear():
    """(8, 8, 3) linear RGB, row 0 the image's top: R a ramp in u, G a checker of the four
    quadrants, B constant."""
    i = np.arange(N_TEX)
    u = (i + 0.5) / N_TEX
    img = np.empty((N_TEX, N_TEX, 3))
    img[:, :, 0] = 0.1 + 0.8 * u[None, :]
    top = (np.arange(N_TEX) < N_TEX // 2)[:, None]  # v > 0.5 (top rows)
    left = (np.arange(N_TEX) < N_TEX // 2)[None, :]
    img[:, :, 1] = np.where(top ^ left, 0.2, 0.7)
    img[:, :, 2] = 0.3
    return img


def _png(img_u8) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.asarray(img_u8, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _u8(img_linear):
    return np.round(np.clip(_srgb_encode(img_linear), 0, 1) * 255).astype(np.uint8)


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64," + base64.b64encode(data).decode()


def _write_gltf(path, *, base_png=None, mr_png=None, normal_png=None, base_factor=(1, 1, 1, 1), metallic=0.0,
                roughness=1.0, with_uv=True):
    """A one-quad glTF 2.0 file, TEXCOORD_0 in glTF's convention (origin at the image's
    top-left): t = (x + ½, ½ − y) at body point (x, y)."""
    pos = V.astype(np.float32)
    tc = np.column_stack([V[:, 0] + 0.5, 0.5 - V[:, 1]]).astype(np.float32)
    idx = F.astype(np.uint16).ravel()
    blobs = [pos.tobytes(), tc.tobytes(), idx.tobytes()]
    views, off = [], 0
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": off, "byteLength": len(b)})
        off += len(b) + (-len(b)) % 4
    data = b"".join(b + b"\0" * ((-len(b)) % 4) for b in blobs)
    attrs = {"POSITION": 0}
    if with_uv:
        attrs["TEXCOORD_0"] = 1
    images, textures = [], []

    def tex(png):
        images.append({"uri": _data_uri(png, "image/png")})
        textures.append({"source": len(images) - 1})
        return {"index": len(textures) - 1}

    pbr = {"baseColorFactor": list(base_factor), "metallicFactor": metallic, "roughnessFactor": roughness}
    mat = {"name": "skin", "pbrMetallicRoughness": pbr}
    if base_png is not None:
        pbr["baseColorTexture"] = tex(base_png)
    if mr_png is not None:
        pbr["metallicRoughnessTexture"] = tex(mr_png)
    if normal_png is not None:
        mat["normalTexture"] = tex(normal_png)
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "plate"}],
        "meshes": [{"primitives": [{"attributes": attrs, "indices": 2, "material": 0}]}],
        "materials": [mat],
        "buffers": [{"byteLength": len(data), "uri": _data_uri(data, "application/octet-stream")}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    if images:
        doc["images"], doc["textures"] = images, textures
    path.write_text(json.dumps(doc))
    return path


def _write_obj(folder, img_u8, kd=(1.0, 1.0, 1.0), texture_name="skin.png", write_png=True):
    """A one-quad OBJ + MTL, ``vt`` in OBJ's convention (origin at the image's bottom-left):
    (x + ½, y + ½) at body point (x, y)."""
    if write_png:
        (folder / texture_name).write_bytes(_png(img_u8))
    (folder / "quad.mtl").write_text(f"newmtl skin\nKd {kd[0]} {kd[1]} {kd[2]}\nmap_Kd {texture_name}\n")
    lines = ["mtllib quad.mtl", "o plate"]
    lines += [f"v {x} {y} {z}" for x, y, z in V]
    lines += [f"vt {x + 0.5} {y + 0.5}" for x, y, _ in V]
    lines += ["usemtl skin"] + [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in F]
    (folder / "quad.obj").write_text("\n".join(lines) + "\n")
    return folder / "quad.obj"


def _bilinear_wrap(img, u, v_top):
    """Texel-centred bilinear lookup with wrap, (u, v_top) with v_top measured from the top."""
    h, w, _ = img.shape
    x = u * w - 0.5
    y = v_top * h - 0.5
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]

    def at(yy, xx):
        return img[yy % h, xx % w]

    return ((1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1))
            + fy * ((1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)))


def _pixel_points():
    """Body points where the pixel centres' rays meet the quad's plane z = 0, and which pixels
    lie a pixel's footprint inside the quad (no edge pixels)."""
    ys, xs = np.mgrid[0:H, 0:W]
    d_cam = np.stack([(xs - CAM.cx) / CAM.fx, (ys - CAM.cy) / CAM.fy, np.ones_like(xs, float)], -1)
    o_body = -R.T @ T
    d_body = d_cam @ R  # R.T @ d per pixel
    t = -o_body[2] / d_body[..., 2]
    p = o_body + t[..., None] * d_body
    foot = 1.2 / CAM.fx
    inside = (np.abs(p[..., 0]) < 0.5 - 1.5 * foot) & (np.abs(p[..., 1]) < 0.5 - 1.5 * foot)
    return p, inside


def _render(model_or_scene, quality="fast", samples=None, seed=0):
    scene = model_or_scene if isinstance(model_or_scene, Scene) else Scene(model_or_scene)
    return render(scene, CAM, R, T, LIGHT, quality=quality, samples=samples, seed=seed).radiance.astype(np.float64)


def _expected_diffuse(texels_linear):
    p, inside = _pixel_points()
    u = p[..., 0] + 0.5
    v_top = 0.5 - p[..., 1]
    rho = _bilinear_wrap(texels_linear, u[inside], v_top[inside])
    E = LIGHT.sun_irradiance_at_target_W_m2 * SUN[2]
    return rho / math.pi * E, inside, p


# ------------------------------------------------------------------------------------ lookups
def test_obj_map_kd_is_the_diffuse_albedo_with_the_origin_at_the_bottom_left(tmp_path):
    pattern = _pattern_linear()
    u8 = _u8(pattern)
    model, _ = load_mesh(_write_obj(tmp_path, u8), unit_scale_m=1.0)
    assert model.components[0].surface is not None
    L = _render(model)
    texels = _srgb_decode(u8 / 255.0)
    want, inside, p = _expected_diffuse(texels)
    np.testing.assert_allclose(L[inside], want, rtol=2e-5, atol=1e-4)
    # and the analytic pattern itself, within the 8-bit quantisation and the bilinear blur of
    # one texel at the checker's edges
    far = (np.abs(p[..., 0][inside]) > 1.0 / N_TEX) & (np.abs(p[..., 1][inside]) > 1.0 / N_TEX)
    u = p[..., 0][inside] + 0.5
    ramp = 0.1 + 0.8 * u
    E = LIGHT.sun_irradiance_at_target_W_m2 * SUN[2]
    inner = far & (u > 0.5 / N_TEX) & (u < 1 - 0.5 / N_TEX)
    np.testing.assert_allclose(L[inside][inner, 0], ramp[inner] / math.pi * E, rtol=0.012)
    g = np.where((p[..., 0][inside] < 0) ^ (p[..., 1][inside] > 0), 0.2, 0.7)
    np.testing.assert_allclose(L[inside][far, 1], g[far] / math.pi * E, rtol=0.012)


def test_gltf_base_colour_texture_with_the_origin_at_the_top_left(tmp_path):
    pattern = _pattern_linear()
    u8 = _u8(pattern)
    model, _ = load_mesh(_write_gltf(tmp_path / "q.gltf", base_png=_png(u8)), unit_scale_m=1.0)
    white, _ = load_mesh(_write_gltf(tmp_path / "w.gltf", base_png=_png(np.full((1, 1, 3), 255))), unit_scale_m=1.0)
    # F0 = 0.04 adds the same specular term to both: their difference is (ρ − 1)/π·E·cosθ
    dL = _render(model) - _render(white)
    want, inside, _ = _expected_diffuse(_srgb_decode(u8 / 255.0) - 1.0)
    np.testing.assert_allclose(dL[inside], want, rtol=2e-4, atol=2e-3)
    # the same file as GLB (trimesh's writer; its JSON chunk read for the texture check too)
    glb = tmp_path / "q.glb"
    trimesh.load_scene(str(tmp_path / "q.gltf"), process=False).export(str(glb))
    again, _ = load_mesh(glb, unit_scale_m=1.0)
    np.testing.assert_array_equal(_render(again), _render(model))


# ------------------------------------------------------------------------ glTF conversions
def test_metallic_roughness_factors_equal_constant_textures_and_the_spec_formulas(tmp_path):
    # (trimesh keeps baseColorFactor as 8 bits: a colour it holds exactly)
    base, metal, rough = np.array([153, 90, 38]) / 255, 0.4, 0.55
    one = _png(np.full((1, 1, 3), 255))
    by_factor, _ = load_mesh(_write_gltf(tmp_path / "a.gltf", base_png=one, base_factor=(*base, 1.0), metallic=metal,
                                         roughness=rough), unit_scale_m=1.0)
    base_u8 = _u8(base[None, None, :])
    mr_u8 = np.array([[[0, round(rough * 255), round(metal * 255)]]], np.uint8)
    by_texture, _ = load_mesh(_write_gltf(tmp_path / "b.gltf", base_png=_png(base_u8), mr_png=_png(mr_u8),
                                          metallic=1.0, roughness=1.0), unit_scale_m=1.0)
    La, Lb = _render(by_factor), _render(by_texture)
    mask = La.sum(axis=2) > 0
    # the texture's 8-bit quantisation of the colour, metallic and roughness
    np.testing.assert_allclose(Lb[mask], La[mask], rtol=0.02)
    # glTF 2.0 Appendix B.3 as a uniform material (α = roughness², F0 = lerp(0.04, base, metallic))
    spec = Material("spec", tuple(base * (1 - metal)), tuple(0.04 * (1 - metal) + base * metal), rough ** 2)
    plain = Scene(TargetModel("plain", (Component("plate", by_factor.components[0].mesh, "white_paint", "bus", 1.0),)))
    object.__setattr__(plain, "_materials", (spec,))
    for q, samples in (("fast", None), ("balanced", None), ("reference", 4)):
        Lu = _render(plain, q, samples, seed=3)
        Lf = _render(by_factor, q, samples, seed=3)
        np.testing.assert_allclose(Lf, Lu, rtol=1e-6, atol=1e-6)


def test_a_flat_normal_map_changes_nothing_and_a_tilted_one_turns_the_normal(tmp_path):
    pattern = _u8(_pattern_linear())
    plain, _ = load_mesh(_write_gltf(tmp_path / "p.gltf", base_png=_png(pattern)), unit_scale_m=1.0)
    flat, _ = load_mesh(_write_gltf(tmp_path / "f.gltf", base_png=_png(pattern),
                                    normal_png=_png(np.full((2, 2, 3), [128, 128, 255]))), unit_scale_m=1.0)
    for q, samples in (("fast", None), ("balanced", None)):
        np.testing.assert_allclose(_render(flat, q, samples), _render(plain, q, samples), rtol=1e-6, atol=1e-6)
    # a constant tangent-space normal (0.3, −0.2, z): n' = normalize(0.3·T − 0.2·B + z·N) with T =
    # +x (u grows with x), B = +y (glTF's +Y up of the texture: v from the bottom grows with y)
    t = np.array([0.3, -0.2, math.sqrt(1 - 0.13)])
    tb = np.round(t * 127 + 128).astype(np.uint8)
    dec = np.clip((tb.astype(float) - 128) / 127, -1, 1)
    n = dec / np.linalg.norm(dec)
    white = _png(np.full((1, 1, 3), 255))
    tilt_tex, _ = load_mesh(_write_gltf(tmp_path / "t.gltf", base_png=_png(pattern), normal_png=_png(tb[None, None])),
                            unit_scale_m=1.0)
    tilt_white, _ = load_mesh(_write_gltf(tmp_path / "tw.gltf", base_png=white, normal_png=_png(tb[None, None])),
                              unit_scale_m=1.0)
    dL = _render(tilt_tex) - _render(tilt_white)
    want, inside, _ = _expected_diffuse(_srgb_decode(pattern / 255.0) - 1.0)
    np.testing.assert_allclose(dL[inside], want * (n @ SUN) / SUN[2], rtol=2e-4, atol=2e-3)


# ------------------------------------------------------------------------------ bad input
def test_unreadable_texture_and_missing_uvs_are_one_line_errors(tmp_path):
    obj = _write_obj(tmp_path, None, texture_name="gone.png", write_png=False)
    with pytest.raises(ValueError, match=r"texture 'gone.png' of material 'skin' cannot be read") as e:
        load_mesh(obj, unit_scale_m=1.0)
    assert "\n" not in str(e.value)
    (tmp_path / "bad.png").write_bytes(b"not a png")
    obj = _write_obj(tmp_path, None, texture_name="bad.png", write_png=False)
    with pytest.raises(ValueError, match=r"texture 'bad.png' of material 'skin' cannot be read"):
        load_mesh(obj, unit_scale_m=1.0)
    # glTF: a missing image file, an embedded one that is not an image (trimesh drops both)
    for uri, name in (("missing.png", "missing.png"), ("data:image/png;base64,AAAA", "an embedded image")):
        gl = _write_gltf(tmp_path / "img.gltf", base_png=_png(np.full((1, 1, 3), 200)))
        doc = json.loads(gl.read_text())
        doc["images"][0] = {"uri": uri}
        gl.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=rf"texture '{name}' of material 'skin' cannot be read") as e:
            load_mesh(gl, unit_scale_m=1.0)
        assert "\n" not in str(e.value)
    gl = _write_gltf(tmp_path / "nouv.gltf", base_png=_png(np.full((1, 1, 3), 200)), with_uv=False)
    with pytest.raises(ValueError, match=r"has a texture but the part has no texture coordinates") as e:
        load_mesh(gl, unit_scale_m=1.0)
    assert "\n" not in str(e.value)
    # presets everywhere when asked: nothing read from the file's materials
    model, _ = load_mesh(gl, unit_scale_m=1.0, file_materials=False)
    assert model.components[0].surface is None
    with pytest.raises(ValueError, match="corner_uv must have shape"):
        Component("x", trimesh.Trimesh(V, F, process=False), "white_paint", "bus",
                  surface=SurfaceMaterial("gltf", corner_uv=np.zeros((3, 3, 2))))


def test_scene_file_uses_the_file_materials_only_when_asked(tmp_path):
    from raytrace.scenefile import load_scene_file
    _write_obj(tmp_path, _u8(_pattern_linear()))
    doc = {"meshes": [{"path": "quad.obj", "material": "white_paint"}],
           "camera": {"K": CAM.K.tolist(), "width": W, "height": H, "R_cam_from_body": R.ravel().tolist(),
                      "t_cam_m": T.tolist()},
           "sun": {"sun_dir_body": SUN.tolist()}}
    for value, textured in ((None, False), ("presets", False), ("file", True)):
        if value is not None:
            doc["meshes"][0]["materials"] = value
        (tmp_path / "s.json").write_text(json.dumps(doc))
        comp = load_scene_file(str(tmp_path / "s.json")).model.components[0]
        assert (comp.surface is not None) is textured
    doc["meshes"][0]["materials"] = "textures"
    (tmp_path / "s.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"meshes\[0\]\.materials must be 'presets' or 'file', got 'textures'"):
        load_scene_file(str(tmp_path / "s.json"))


# ------------------------------------------------------------------ balanced vs reference
def _floor_and_wall(floor: Component, size_m: float) -> TargetModel:
    """``floor`` (in the plane z = 0, |x|, |y| ≤ size/2) and a white wall standing on its +y edge
    that bounces sunlight onto it."""
    h = size_m / 2
    wall = trimesh.Trimesh(np.array([[-h, h, 0], [h, h, 0], [h, h, size_m], [-h, h, size_m]]),
                           np.array([[0, 2, 1], [0, 3, 2]]), process=False)
    return TargetModel("floor_wall", (floor, Component("wall", wall, "white_paint", "bus", 1.0)))


def _quad(size_m: float):
    return trimesh.Trimesh(V * size_m, F, process=False)


def _oblique_view(size_m: float):
    """A camera above the floor's −y side looking at its centre, the image's x along the body x."""
    eye = np.array([0.0, -0.9, 1.1]) * size_m
    z = -eye / np.linalg.norm(eye)
    x = np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    Rv = np.stack([x, y, z])
    return Rv, -Rv @ eye


def _balanced_error(model, size_m: float, spp: int = 64):
    scene = Scene(model)
    Rv, tv = _oblique_view(size_m)
    light = Lighting(sun_dir_body=tuple(np.array([0.2, 0.5, 0.84]) / np.linalg.norm([0.2, 0.5, 0.84])), earth=None,
                     ambient_radiance_W_m2_sr=1.0)
    runs = [render(scene, CAM, Rv, tv, light, quality="reference", samples=spp, seed=s) for s in (1, 2)]
    a, b = (r.radiance.astype(np.float64) for r in runs)
    mask = runs[0].geometry.mask

    def rel(x, y):
        return float(np.sqrt(((x[mask] - y[mask]) ** 2).sum() / (y[mask] ** 2).sum()))

    ref = (a + b) / 2
    noise = rel(a, b) / 2
    img = render(scene, CAM, Rv, tv, light, quality="balanced", seed=3).radiance.astype(np.float64)
    e = rel(img, ref)
    return math.sqrt(max(e * e - noise * noise, 0.0)), noise, int(mask.sum())


def _bumpy_gltf(tmp_path):
    """Base colour, metallic-roughness and normal textures that all vary (8×8 texels)."""
    i = np.arange(N_TEX)
    uu, vv = np.meshgrid((i + 0.5) / N_TEX, (i + 0.5) / N_TEX)
    mr = np.zeros((N_TEX, N_TEX, 3))
    mr[..., 1] = 0.35 + 0.5 * uu  # roughness
    mr[..., 2] = np.where(vv > 0.5, 0.9, 0.0)  # metal in the top half
    nrm = np.stack([0.25 * np.sin(2 * np.pi * uu), 0.25 * np.cos(2 * np.pi * vv), np.ones_like(uu)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    nrm_u8 = np.round(nrm * 127 + 128).astype(np.uint8)
    return _write_gltf(tmp_path / "bumpy.gltf", base_png=_png(_u8(_pattern_linear())),
                       mr_png=_png(np.round(mr * 255).astype(np.uint8)), normal_png=_png(nrm_u8), metallic=1.0,
                       roughness=1.0)


def test_balanced_matches_the_reference_on_a_textured_floor(tmp_path):
    floor, _ = load_mesh(_bumpy_gltf(tmp_path), unit_scale_m=1.0)
    comp = floor.components[0]
    err, noise, n = _balanced_error(_floor_and_wall(comp, 1.0), 1.0)
    print(f"textured: balanced {100 * err:.2f} %, reference noise {100 * noise:.2f} %, {n} px")
    assert n > 1000 and noise < 0.03
    assert err < 0.02


@pytest.mark.parametrize("preset, size_m", [("gold_mli", 0.12), ("silver_mli", 0.12), ("solar_cell", 0.25)])
def test_balanced_matches_the_reference_on_the_procedural_materials(preset, size_m):
    floor = Component("floor", _quad(size_m), preset, "bus", 1.0)
    model = _floor_and_wall(floor, size_m)
    mat_par = Scene(model).material_tables[0]
    assert mat_par[0, 0] != 0  # procedural, not the uniform preset
    err, noise, n = _balanced_error(model, size_m)
    print(f"{preset}: balanced {100 * err:.2f} %, reference noise {100 * noise:.2f} %, {n} px")
    assert n > 1000 and noise < 0.03
    assert err < 0.02


# ------------------------------------------------------------------ procedural materials
def _tables(preset: str):
    """A 1 m × 0.5 m panel (its first principal axis x) of ``preset`` and its material tables."""
    mesh = trimesh.Trimesh(V * [1.0, 0.5, 0.0], F, process=False)
    model = TargetModel("one", (Component("panel", mesh, preset, "bus", 1.0),))
    scene = Scene(model)
    mats = scene.materials
    arrays = (np.array([m.diffuse for m in mats]), np.array([m.f0 for m in mats]),
              np.array([m.roughness for m in mats]))
    return scene, arrays, scene.material_tables


def test_the_solar_grid_box_filter_and_mean_against_point_samples():
    from raytrace import _texture as tx
    from raytrace.surfaces import SOLAR_BUSBAR_DIFFUSE, SOLAR_BUSBAR_M, SOLAR_GAP_M
    scene, (d, f0, a), (par, fuv, atlas, varying) = _tables("solar_cell")
    assert varying

    def at(b1, b2, foot):
        return tx.material_at(0, 0, b1, b2, 0.0, 0.0, 1.0, foot, d, f0, a, par, fuv, atlas)

    # face 0 is (v0, v1, v2): the point b0·v0 + b1·v1 + b2·v2
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 1, (20000, 2))
    pts = pts[pts.sum(1) <= 1]
    rho = np.array([at(b1, b2, 0.0)[0] for b1, b2 in pts])
    # the area fractions of a 40 × 80 mm cell with its 1 mm gaps and 1 mm busbar
    pu, pv = 0.040 + SOLAR_GAP_M, 0.080 + SOLAR_GAP_M
    f_cell = (1 - SOLAR_GAP_M / pu) * (1 - (SOLAR_GAP_M + SOLAR_BUSBAR_M) / pv)
    f_bus = (1 - SOLAR_GAP_M / pu) * SOLAR_BUSBAR_M / pv
    want = f_cell * d[0, 0] + f_bus * SOLAR_BUSBAR_DIFFUSE + (1 - f_cell - f_bus) * 0.30
    assert at(0.3, 0.3, -1.0)[0] == pytest.approx(want, rel=1e-12)
    assert rho.mean() == pytest.approx(want, rel=0.05)  # Monte Carlo over ~10⁴ points
    # the box filter over a footprint w: the mean of point samples across it along u (x, the
    # panel's first principal axis: b1 moves the point along x by b1 metres), at y = −0.1 m,
    # inside a cell row (v = 0.15 m: 69 mm into its 81 mm period), where only u's gaps vary
    assert abs(par[0, tx.P_AX1]) == pytest.approx(1.0)
    filtered, sampled = [], []
    for b1 in np.linspace(0.2, 0.241, 83):  # one period of u, every 0.5 mm
        w = 0.003  # [m]: b1 ± 0.0015
        s = np.linspace(b1 - 0.0015, b1 + 0.0015, 1501)
        sampled.append(np.mean([at(x, 0.3, 0.0)[0] for x in s]))
        filtered.append(at(b1, 0.3, w)[0])
    np.testing.assert_allclose(filtered, sampled, atol=1e-3)
    assert np.ptp(filtered) > 0.05  # some windows cross a gap
    # the specular lobe is the preset's everywhere (cover glass)
    assert at(0.3, 0.3, 0.0)[3:7] == pytest.approx((*f0[0], a[0]))


def test_mli_crinkle_seen_from_afar_is_the_preset_lobe():
    from raytrace import _texture as tx
    for preset in ("gold_mli", "silver_mli"):
        _, (d, f0, a), (par, fuv, atlas, _) = _tables(preset)
        near = tx.material_at(0, 0, 0.3, 0.3, 0.0, 0.0, 1.0, 0.0, d, f0, a, par, fuv, atlas)
        far = tx.material_at(0, 0, 0.3, 0.3, 0.0, 0.0, 1.0, -1.0, d, f0, a, par, fuv, atlas)
        assert far[7:] == (0.0, 0.0, 1.0)  # unperturbed
        assert far[6] == pytest.approx(0.32, abs=0.005)  # α² + 2σ² of the crinkle: the preset's wide lobe
        assert near[6] == pytest.approx(0.15) and near[9] < 1.0  # a glossy foil, its normal tilted
