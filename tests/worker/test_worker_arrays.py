"""The render worker's CPU side, no GL needed: shader sources, scene -> buffer arrays, scene
contract checks, the camera, and the messages for a missing or too old GL."""

from __future__ import annotations

import dataclasses
from importlib import resources
from typing import Any, ClassVar

import numpy as np
import pytest

from forest.errors import LimitError, SceneError
from forest.geometry.pieces import QUAD_ST
from forest.gl import shaders
from forest.gl.context import GLUnavailableError, create_context
from forest.usd.read import SceneArrays
from schemas.tileset import DEFAULT_MANIFEST
from tests.helpers_skin import skin
from worker.render.camera import box_corners, frame_box
from worker.render.scene_buffers import (
    InstanceLayout,
    SceneBuffers,
    check_scene,
    gl_matrices,
    patch_vertices,
    scene_bounds,
)
from worker.render.textures import procedural_tiles

# -- shaders -------------------------------------------------------------------------------


@pytest.mark.parametrize("stage", shaders.STAGES)
def test_shader_files_ship_in_the_package(stage: str) -> None:
    text = (resources.files("shaders") / f"piece.{stage}").read_text(encoding="utf-8")
    assert text.startswith("#version 430 core\n")


def test_defines_go_after_version_and_keep_line_numbers() -> None:
    src = shaders.compose("piece.tese", {"CAPTURE": True})
    lines = src.splitlines()
    assert lines[0] == "#version 430 core"
    assert lines[1] == "#define CAPTURE"
    assert lines[2] == "#line 2"
    assert src.endswith(shaders.load("piece.tese")[len("#version 430 core\n") :])
    assert shaders.compose("piece.tese") == shaders.load("piece.tese")


def test_a_define_no_stage_uses_fails() -> None:
    with pytest.raises(shaders.ShaderError, match="CAPTUER"):
        shaders.sources("piece", {"CAPTUER": True})
    with pytest.raises(shaders.ShaderError, match="not used by this shader"):
        shaders.compose("piece.vert", {"CAPTURE": True})


def test_defines_reach_only_the_stages_that_use_them() -> None:
    src = shaders.sources("piece", {"CAPTURE": True, "ID_OUTPUT": True})
    assert set(src) == {
        "vertex_shader",
        "tess_control_shader",
        "tess_evaluation_shader",
        "fragment_shader",
    }
    assert "#define CAPTURE" in src["tess_evaluation_shader"]
    assert "#define ID_OUTPUT" in src["fragment_shader"]
    assert "#define" not in src["vertex_shader"]


def test_missing_shader_is_a_clear_error() -> None:
    with pytest.raises(shaders.ShaderError, match="no such shader"):
        shaders.load("nothing.vert")
    with pytest.raises(shaders.ShaderError, match="plain file names"):
        shaders.load("../forest/cli.py")


# -- scene -> buffers ----------------------------------------------------------------------


def test_patch_vertices_are_the_quads_corners_in_winding_order(mixed_scene: SceneArrays) -> None:
    for piece in mixed_scene.pieces:
        v = patch_vertices(piece)
        assert len(v) == 4 * len(piece.quads)
        corners = piece.quads.reshape(-1)
        np.testing.assert_allclose(v["position"], piece.positions[corners], rtol=1e-6)
        np.testing.assert_array_equal(v["joints"], piece.joint_indices[corners])
        np.testing.assert_array_equal(
            v["st"].reshape(-1, 4, 2), np.broadcast_to(QUAD_ST, (len(piece.quads), 4, 2))
        )


def test_instance_layout_groups_types_and_packs_tiles(mixed_scene: SceneArrays) -> None:
    lay = InstanceLayout.from_scene(mixed_scene)
    types = mixed_scene.proto_indices[lay.order]
    assert (np.diff(types) >= 0).all()
    for t in range(len(mixed_scene.pieces)):
        sl = slice(lay.first[t], lay.first[t] + lay.count[t])
        assert (types[sl] == t).all()
    # every sorted slot finds its own quads' tiles at its tile offset
    for slot, i in enumerate(lay.order):
        q = len(mixed_scene.pieces[mixed_scene.proto_indices[i]].quads)
        off = lay.records["tile_offset"][slot]
        np.testing.assert_array_equal(lay.tiles[off : off + q], mixed_scene.tile_indices[i, :q])
    assert lay.tiles.min() >= 0
    assert (lay.records["id"] == lay.order).all()


def test_gl_matrices_are_column_major() -> None:
    m = np.arange(16.0).reshape(4, 4)  # row-major numpy, column-vector convention
    flat = gl_matrices(m[None])[0].reshape(-1)
    # GLSL mat4 memory is column after column: the first four floats are m's first column
    np.testing.assert_array_equal(flat[:4], m[:, 0])
    np.testing.assert_array_equal(flat[12:], m[:, 3])


def test_scene_bounds_hold_every_skinned_vertex(mixed_scene: SceneArrays) -> None:
    lo, hi = scene_bounds(mixed_scene, frame=2)
    s = mixed_scene
    for t, piece in enumerate(s.pieces):
        inst = np.nonzero(s.proto_indices == t)[0]
        pos, _ = skin(s.palette(2), s.bone_offset[inst], piece)
        assert (pos >= lo - 1e-9).all() and (pos <= hi + 1e-9).all()


def _broken(scene: SceneArrays, **changes: Any) -> SceneArrays:
    return dataclasses.replace(scene, **changes)


def test_bone_offset_past_the_palette_names_the_attribute(mixed_scene: SceneArrays) -> None:
    off = mixed_scene.bone_offset.copy()
    off[3] = mixed_scene.n_bones
    with pytest.raises(SceneError) as err:
        check_scene(_broken(mixed_scene, bone_offset=off))
    assert err.value.path == "/World/Forest/Pieces.primvars:forest:boneOffset"
    assert "instance 3" in err.value.message


def test_tile_index_outside_the_tile_set_names_the_attribute(mixed_scene: SceneArrays) -> None:
    tiles = mixed_scene.tile_indices.copy()
    tiles[5, 0] = 99
    with pytest.raises(SceneError) as err:
        check_scene(_broken(mixed_scene, tile_indices=tiles), n_slices=DEFAULT_MANIFEST.n_slices)
    assert err.value.path == "/World/Forest/Pieces.primvars:forest:tileIndices"
    assert "99" in err.value.message
    tiles[5, 0] = -1  # padding inside a piece's quads
    with pytest.raises(SceneError, match="-1"):
        check_scene(_broken(mixed_scene, tile_indices=tiles), n_slices=DEFAULT_MANIFEST.n_slices)


def test_joint_index_outside_the_skeleton_names_the_prototype(mixed_scene: SceneArrays) -> None:
    piece = mixed_scene.pieces[0]
    ji = piece.joint_indices.copy()
    ji[0, 0] = 17
    pieces = (dataclasses.replace(piece, joint_indices=ji), *mixed_scene.pieces[1:])
    with pytest.raises(SceneError) as err:
        check_scene(_broken(mixed_scene, pieces=pieces))
    assert (
        err.value.path
        == f"/World/Forest/Pieces/Prototypes/{piece.name}.primvars:forest:jointIndices"
    )


def test_non_finite_rotations_are_refused(mixed_scene: SceneArrays) -> None:
    rot = mixed_scene.joint_rotations.copy()
    rot[1, 4, 0] = np.nan
    with pytest.raises(SceneError, match="non-finite") as err:
        check_scene(_broken(mixed_scene, joint_rotations=rot))
    assert err.value.path.endswith(".forest:jointRotations")


def test_buffers_beyond_the_driver_limit_name_the_attribute(mixed_scene: SceneArrays) -> None:
    class SmallDriver:  # checked before any GL object is made
        info: ClassVar[dict[str, int]] = {"GL_MAX_SHADER_STORAGE_BLOCK_SIZE": 1024}

    with pytest.raises(LimitError) as err:
        SceneBuffers(SmallDriver(), mixed_scene)  # type: ignore[arg-type]
    assert err.value.path == "/World/Forest/Pieces.forest:boneParents"
    assert "more than this driver's storage block limit of 0.000977 MiB" in err.value.message


def test_placeholder_tiles_share_their_border() -> None:
    from schemas.tileset import DEFAULT_MANIFEST

    img = procedural_tiles(DEFAULT_MANIFEST, 12, size=32).slices.astype(int)
    lum = img[..., :3].sum(axis=-1)
    # same class, same border: the outermost texels agree to rounding; insides differ
    for edge in (lum[:, 0, :], lum[:, -1, :], lum[:, :, 0], lum[:, :, -1]):
        assert np.abs(edge[:8] - edge[0]).max() <= 30
    assert np.abs(lum[1, 8:24, 8:24] - lum[0, 8:24, 8:24]).max() > 30


# -- camera --------------------------------------------------------------------------------


@pytest.mark.parametrize("aspect", [0.5, 1.0, 2.0])
def test_frame_box_fits_the_box_tightly(aspect: float) -> None:
    lo, hi = np.array([-10.0, 0.0, -4.0]), np.array([12.0, 6.0, 5.0])
    cam = frame_box(lo, hi, aspect)
    clip = np.c_[box_corners(lo, hi), np.ones(8)] @ cam.view_projection().T
    ndc = clip[:, :3] / clip[:, 3:]
    assert (np.abs(ndc[:, :2]) <= 1.0).all()
    assert np.abs(ndc[:, :2]).max() > 0.85  # tight: a corner touches the margin
    assert (ndc[:, 2] > -1).all() and (ndc[:, 2] < 1).all()  # between near and far


# -- errors when GL is missing -------------------------------------------------------------


def _refuse(message: str) -> Any:
    def create_context(**kwargs: Any) -> Any:
        raise Exception(message)

    return create_context


def test_missing_libegl_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    import moderngl

    monkeypatch.setattr(moderngl, "create_context", _refuse("libEGL.so not loaded"))
    with pytest.raises(GLUnavailableError) as err:
        create_context()
    assert err.value.path == "gl.egl"
    assert "apt-get install libegl1 libegl-mesa0" in str(err.value)


def test_too_old_gl_says_which_version(monkeypatch: pytest.MonkeyPatch) -> None:
    import moderngl

    class Old:
        version_code = 330
        info: ClassVar[dict[str, str]] = {"GL_RENDERER": "Ancient GPU"}

        def release(self) -> None:
            pass

    def create(**kwargs: Any) -> Any:
        if "require" in kwargs:
            raise Exception("eglCreateContext failed (0x3009)")
        return Old()

    monkeypatch.setattr(moderngl, "create_context", create)
    with pytest.raises(GLUnavailableError) as err:
        create_context()
    assert err.value.path == "gl.version"
    assert "OpenGL 3.3 from Ancient GPU is too old, 4.3 is needed" in str(err.value)
