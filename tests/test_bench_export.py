"""forest bench export measures what it wrote: the forms' triangles and joints come from the
files (a .glb's JSON, a USD scene's composed levels), so they agree with the writers' own
figures and each form is written once."""

from __future__ import annotations

from bench.export import FORMS, POSED, run_export_bench


def test_export_bench_reads_every_form_back() -> None:
    lines: list[str] = []
    rows = run_export_bench("almond", 1, 2, 3, echo=lines.append)
    assert [r["form"] for r in rows] == [f.name for f in FORMS]
    for row in rows:
        assert row["bytes"] > 100_000 and row["write_s"] > 0
        if row["form"] == POSED:  # instanced pieces: no baked levels, no skeleton
            assert row["vs_posed_usdc"] == 1.0 and not row["triangles_per_tree"]
            continue
        # the film profile keeps a joint per bone; every other form is cut for its consumer
        assert 1 <= row["joints_per_tree"] <= (1 << 62 if "film" in row["form"] else 1024)
        lod0 = row["triangles_per_tree"][0]
        assert 10_000 < lod0 < 300_000
        # every further level is lighter than the one before
        tris = list(row["triangles_per_tree"].values())
        assert tris == sorted(tris, reverse=True)
    usdc, glb = rows[0], rows[2]
    assert glb["joints_per_tree"] <= 256 and usdc["joints_per_tree"] <= 1024
    assert "ez-tree" in lines[-1]
    assert (
        lines[-2].startswith(".glb write time / posed .usdc's") and "film, quantized" in lines[-2]
    )
