"""Labelled street scenes and COCO data: boxes match the drawn objects,
sizes, classes and light as asked, deterministic, COCO round trip, loader errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from optix_e2e.scenes.coco import CocoDetection, CocoFormatError, write_street_coco
from optix_e2e.scenes.street import CATEGORIES, street_scene

SIZE = (128, 192)


def test_each_box_is_the_visible_extent_of_the_object_it_labels():
    # drawing the same scene without object k changes pixels only inside its box (traffic
    # lights: and their pole, below it), on every edge row and column of the box, and on at
    # least the visible share the labeller required
    n = 0
    for seed in range(6):
        s = street_scene(SIZE, seed)
        for (x0, y0, x1, y1), cls, k in zip(s.boxes.int().tolist(), s.labels.tolist(), s.object_index):
            diff = (street_scene(SIZE, seed, hide=frozenset({k})).radiance != s.radiance).any(0).numpy()
            inside = diff[y0:y1, x0:x1]
            assert inside[0].any() and inside[-1].any() and inside[:, 0].any() and inside[:, -1].any()
            outside = diff.copy()
            outside[y0:y1, x0:x1] = False
            if cls == 4:
                outside[y1:] = False  # the pole
            assert not outside.any(), (seed, k, cls)
            assert inside.mean() >= 0.1
            n += 1
    assert n >= 20


@pytest.mark.slow
def test_scenes_are_seeded_and_have_the_sizes_classes_and_light_asked_for():
    a, b, c = street_scene(SIZE, 7), street_scene(SIZE, 7), street_scene(SIZE, 8)
    assert torch.equal(a.radiance, b.radiance) and torch.equal(a.boxes, b.boxes)
    assert not torch.equal(a.radiance, c.radiance)
    H = 240
    heights, classes, dark = [], set(), 0
    for seed in range(60):
        s = street_scene((H, 360), seed)
        assert s.radiance.shape == (3, H, 360) and bool(torch.isfinite(s.radiance).all())
        assert s.radiance.dtype == s.light.dtype == torch.float32
        heights += (s.boxes[:, 3] - s.boxes[:, 1]).tolist()
        classes |= set(s.labels.tolist())
        lo = float(s.light.min())
        assert 0.01 - 1e-6 <= lo and float(s.light.max()) <= 1.0
        dark += lo <= 0.1  # a region with 10x or less of the sunlight
        assert len(s.boxes) == len(s.labels) == len(s.object_light)
    assert classes == {c["id"] for c in CATEGORIES}
    assert min(heights) <= 10 and max(heights) >= H / 4, (min(heights), max(heights))
    assert dark >= 45


def test_coco_round_trip(tmp_path):
    ann = write_street_coco(tmp_path, 4, SIZE, seed=3)
    ds = CocoDetection(tmp_path / "images", ann)
    assert len(ds) == 4 and ds.categories == {c["id"]: c["name"] for c in CATEGORIES}
    from optix_e2e.color import linear_to_srgb

    for i in range(4):
        img, t = ds[i]
        s = street_scene(SIZE, np.random.default_rng([3, i]))
        assert torch.equal(t["boxes"], s.boxes) and torch.equal(t["labels"], s.labels) and t["image_id"] == i + 1
        assert img.shape == (3, *SIZE)
        assert float((img - linear_to_srgb(s.radiance.clamp(0, 1))).abs().max()) <= 0.5 / 255 + 1e-6


def _bad(tmp_path, data, match, raw=None):
    ann = tmp_path / "bad.json"
    ann.write_text(raw if raw is not None else json.dumps(data))
    with pytest.raises(CocoFormatError, match=match):
        CocoDetection(tmp_path / "images", ann)


def test_the_coco_loader_names_each_problem(tmp_path):
    ann = write_street_coco(tmp_path, 2, (64, 64), seed=0)
    good = json.loads(ann.read_text())
    with pytest.raises(CocoFormatError, match="not found"):
        CocoDetection(tmp_path / "images", tmp_path / "missing.json")
    _bad(tmp_path, None, r"invalid JSON at line 2, column", raw='{"images": [],\n "annotations": ]}')
    _bad(tmp_path, [], "top level must be an object")
    _bad(tmp_path, {**good, "images": {}}, "'images' must be list")
    d = json.loads(json.dumps(good))
    d["annotations"][0]["category_id"] = 99
    _bad(tmp_path, d, f"annotation id {d['annotations'][0]['id']}: category_id 99 is not among the categories")
    d = json.loads(json.dumps(good))
    d["annotations"][0]["bbox"] = [60, 60, 30, 30]
    _bad(tmp_path, d, "lies outside its image street_0_000000.png")
    d = json.loads(json.dumps(good))
    d["annotations"][0]["bbox"] = [1, 2, float("nan"), 3]
    _bad(tmp_path, None, "four finite numbers", raw=json.dumps(d))
    d = json.loads(json.dumps(good))
    d["annotations"][1]["id"] = d["annotations"][0]["id"]
    _bad(tmp_path, d, "duplicate annotation id")
    d = json.loads(json.dumps(good))
    d["images"][1]["file_name"] = "nowhere.png"
    _bad(tmp_path, d, r"images\[1\]: image file .*nowhere.png not found")
    d = json.loads(json.dumps(good))
    d["annotations"][0]["image_id"] = 42
    _bad(tmp_path, d, "image_id 42 is not among the images")
    d = json.loads(json.dumps(good))
    d["images"][0]["width"] = 65
    (tmp_path / "ok.json").write_text(json.dumps(d))
    ds = CocoDetection(tmp_path / "images", tmp_path / "ok.json")
    with pytest.raises(CocoFormatError, match="image is 64 x 64, the annotation file says 65 x 64"):
        ds[0]


def test_the_scenes_command_writes_a_coco_set_and_refuses_bad_sizes(tmp_path):
    from click.testing import CliRunner

    from optix_e2e.cli import main

    r = CliRunner().invoke(
        main, ["scenes", "street", "--out", str(tmp_path / "s"), "-n", "3", "--size", "64x96", "--quiet"]
    )
    assert r.exit_code == 0, r.output
    line = json.loads(r.output.strip().splitlines()[-1])
    assert line["images"] == 3 and line["objects"] == sum(line["per_class"].values())
    ds = CocoDetection(tmp_path / "s" / "images", line["annotations"])
    assert len(ds) == 3 and ds[2][0].shape == (3, 64, 96)
    r = CliRunner().invoke(main, ["scenes", "street", "--out", str(tmp_path / "t"), "-n", "1", "--size", "big"])
    assert r.exit_code == 2 and "expected HxW" in r.output
