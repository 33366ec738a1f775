"""Bark of an uploaded scene, through the render job as the worker runs it: a ``.usdz`` (the
skinned trees only, no pieces) is refused by name; a ``.usdc`` (no package: no textures) whose
material names a folder renders the shipped set its material names and says so without a
path; a shipped set missing from the installation is an error naming the set, not
placeholder bark."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from farm.artifacts import ArtifactStore
from forest.bark import tilesets
from forest.errors import ForestError
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from schemas.metrics import RenderMetrics
from worker.jobs.context import JobContext, Outcome
from worker.jobs.render import run_render

JOB = "d" * 32


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("upload")
    shutil.copytree(tilesets.set_dir("oak"), folder / "tiles")
    forest = generate_forest(load_preset("alternating"), 3, ForestOptions(trees=1))
    return {
        fmt: write_scene(forest, folder / f"scene.{fmt}", tiles="tiles") for fmt in ("usdz", "usdc")
    }


def render_upload(scene: Path, tmp_path: Path) -> tuple[Outcome, RenderMetrics]:
    store = ArtifactStore(tmp_path / "artifacts")
    name = f"upload{scene.suffix}"
    store.publish(JOB, Path(shutil.copy(scene, tmp_path / name)), name)
    params = {
        "forest_job": None, "scene": name, "width": 32, "height": 24, "tess_max": 1.0,
        "frame": 0, "frames": 1,
    }  # fmt: skip
    out = run_render(JobContext(JOB, params, store.scratch(JOB), store))
    text = out.files["metrics.json"].read_text()
    assert str(tmp_path) not in text and "/tmp" not in text, text
    return out, RenderMetrics.model_validate_json(text)


def test_a_usdz_is_refused_by_name(scenes: dict[str, Path], tmp_path: Path) -> None:
    """A .usdz holds the skinned trees only (ARKit allows no PointInstancer): nothing the
    renderer's pieces come from."""
    with pytest.raises(ForestError, match="only the 'skinned' trees"):
        render_upload(scenes["usdz"], tmp_path)


def test_a_usdc_renders_the_shipped_set(scenes: dict[str, Path], tmp_path: Path) -> None:
    # the artifact folder gets a "tiles" folder beside the upload: it must not be read
    (tmp_path / "artifacts" / JOB / "tiles").mkdir(parents=True)
    out, metrics = render_upload(scenes["usdc"], tmp_path)
    assert metrics.textures == "shipped bark tile set 'default'"
    assert metrics.warnings == [
        "the upload carries no bark tiles its material names: shipped default bark"
    ]
    assert out.result["warnings"] == metrics.warnings


def test_a_missing_shipped_set_is_an_error(
    scenes: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tilesets, "set_dir", lambda name: tmp_path / "not-installed" / name)
    with pytest.raises(ForestError) as exc:
        render_upload(scenes["usdc"], tmp_path)
    assert str(exc.value) == (
        "bark: the shipped bark tile set 'default' is missing from this installation"
    )
