"""``fingerloc features`` on image files written to disk."""

from __future__ import annotations

import numpy as np
from PIL import Image

from fingerloc.angles import dist_as
from fingerloc.io.jsonl import read_observations

from ._cli import run_cli as run
from .features_world import make_donut, paint_panorama


def save(path, img, **kw):
    Image.fromarray((np.clip(img, 0, 1) * 255).round().astype(np.uint8)).save(path, **kw)
    return path


def test_panorama_jpeg_to_jsonl(tmp_path, capsys):
    img1, edges1, centres1, _ = paint_panorama(seed=1)
    img2, _, _, _ = paint_panorama(seed=2, patches=((200, 240, 60.0),))
    a = save(tmp_path / "a.jpg", img1, quality=80)
    b = save(tmp_path / "b.png", img2)
    out_json = tmp_path / "obs.jsonl"
    code, out, err = run(capsys, "features", a, b, "--place", "office-3", "--json", out_json)
    assert code == 0, err
    assert "vertical edges (12)" in out and "colour patches (3)" in out
    assert ":A(" in out  # the red poster's hue letter
    obs = read_observations(out_json)
    assert len(obs) == 2 and all(o.label == "office-3" and o.full_fov for o in obs)
    assert obs[0].ve.size == edges1.size and obs[0].cp.size == centres1.size
    assert obs[1].cp.size == 1 and 45 <= obs[1].cp_hue[0] <= 75


def test_bearing_offset_turns_everything(tmp_path, capsys):
    img, _, _, _ = paint_panorama(seed=1)
    p = save(tmp_path / "a.png", img)
    o0, o1 = tmp_path / "0.jsonl", tmp_path / "1.jsonl"
    assert run(capsys, "features", p, "--json", o0)[0] == 0
    assert run(capsys, "features", p, "--bearing-offset-deg", "30", "--json", o1)[0] == 0
    a, b = read_observations(o0)[0], read_observations(o1)[0]
    assert np.allclose(dist_as(a.ve + np.deg2rad(30), b.ve), 0, atol=1e-6)


def test_omni_image(tmp_path, capsys):
    img, edges, centres, _ = paint_panorama(h=90, shading=False, sun=False, noise=0.0)
    donut, (cx, cy) = make_donut(img, size=600, r_in=60.0, r_out=290.0)
    p = save(tmp_path / "omni.png", donut)
    out_json = tmp_path / "o.jsonl"
    code, _out, err = run(
        capsys, "features", p, "--kind", "omni", "--center", cx, cy, "--radii", 60, 290, "--json", out_json
    )
    assert code == 0, err
    obs = read_observations(out_json)[0]
    assert obs.ve.size == edges.size and obs.cp.size == centres.size


def test_bad_inputs_name_the_problem(tmp_path, capsys):
    bad = tmp_path / "notes.jpg"
    bad.write_text("not an image")
    code, _, err = run(capsys, "features", bad)
    assert code == 2 and "notes.jpg" in err and err.startswith("error:")
    code, _, err = run(capsys, "features", tmp_path / "missing.png")
    assert code == 2 and "missing.png" in err
    img, _, _, _ = paint_panorama()
    p = save(tmp_path / "a.png", img)
    code, _, err = run(capsys, "features", p, "--kind", "omni")
    assert code == 2 and "--center" in err
    code, _, err = run(capsys, "features", p, "--kind", "lidar")
    assert code == 2 and "lidar" in err
    code, _, err = run(capsys, "features", p, "--band", "0.8", "0.2")
    assert code == 2 and "--band" in err


def test_bench_features_small(tmp_path, capsys):
    import json

    out = tmp_path / "b.json"
    code, stdout, err = run(capsys, "bench", "features", "--offices", 1, "--poses", 2, "--no-omni", "--json", out)
    assert code == 0, err
    assert "precision" in stdout
    res = json.loads(out.read_text())
    assert res["protocol"]["measurements"] == 2
    for t in ("c", "Ex", "B", "VE", "CP"):
        s = res["types"][t]
        assert s["precision"] is None or 0 <= s["precision"] <= 1
        assert s["recall"] is None or 0 <= s["recall"] <= 1
