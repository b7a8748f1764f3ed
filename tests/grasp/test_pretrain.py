"""Tests for sern_jax.grasp.model.pretrain and artifacts: metrics against hand-computed values, a
tiny pretraining run end to end (artefacts written and loaded back), resume after a
checkpoint, the hard-set screen's rule, and θ0 loading / hard_set / install."""

import json
import shutil
import warnings

import jax
import numpy as np
import pytest
import scipy.stats

from sern_jax.infra import io
from sern_jax.grasp.model import artifacts, dataset, pretrain
from sern_jax.grasp.world import objects

CONFIG = pretrain.PretrainConfig(epochs=2, batch_size=32, heldout_objects=1,
                                 heldout_poses=1, heldout_trials=2, core_k=4)


# ----------------------------------------------------------------------------- metrics


def test_classification_metrics_hand_computed():
    prob = np.array([0.1, 0.4, 0.4, 0.8])
    label = np.array([0, 0, 1, 1])
    m = pretrain.classification_metrics(prob, label)
    # pairs (pos, neg): (.4,.1) 1, (.4,.4) tie 1/2, (.8,.1) 1, (.8,.4) 1 -> 3.5 / 4
    assert m["roc_auc"] == pytest.approx(0.875)
    assert m["accuracy"] == pytest.approx(0.75)  # predictions (p >= .5) 0, 0, 0, 1
    assert m["accuracy_majority_class"] == pytest.approx(0.5)
    assert m["positive_rate"] == pytest.approx(0.5)
    assert m["brier"] == pytest.approx((0.01 + 0.16 + 0.36 + 0.04) / 4)
    # bins [.1,.2): |.1 - 0|, [.4,.5): |.4 - .5| x2, [.8,.9): |.8 - 1|
    assert m["ece"] == pytest.approx((0.1 + 2 * 0.1 + 0.2) / 4)
    assert [b["count"] for b in m["reliability"]] == [1, 2, 1]
    assert m["n"] == 4


def test_auc_with_ties_matches_mann_whitney():
    rng = np.random.default_rng(0)
    prob = rng.integers(0, 5, 300) / 4.0  # heavy ties
    label = rng.random(300) < 0.2 + 0.6 * prob
    m = pretrain.classification_metrics(prob, label)
    u = scipy.stats.mannwhitneyu(prob[label], prob[~label]).statistic
    assert m["roc_auc"] == pytest.approx(u / (label.sum() * (~label).sum()), abs=1e-12)
    # a constant predictor has AUC 1/2
    assert pretrain.classification_metrics(np.full(300, 0.3), label)["roc_auc"] == 0.5


def test_calibrated_predictor_has_ece_near_zero():
    rng = np.random.default_rng(1)
    prob = rng.random(200_000)
    label = rng.random(prob.size) < prob
    assert pretrain.classification_metrics(prob, label)["ece"] < 0.01
    # against exact frequencies the calibration error is 0
    assert pretrain.classification_metrics(prob, label, freq=prob)["ece"] == pytest.approx(0)
    # a miscalibrated one (squashed towards 1/2) is caught
    assert pretrain.classification_metrics(0.5 + 0.5 * (prob - 0.5), label)["ece"] > 0.1


def test_metrics_degenerate_inputs_give_nan_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = pretrain.classification_metrics(np.zeros(0), np.zeros(0))
        assert m["n"] == 0 and np.isnan(m["accuracy"]) and np.isnan(m["roc_auc"])
        one_class = pretrain.classification_metrics(np.array([0.2, 0.9]), np.array([1, 1]))
    assert np.isnan(one_class["roc_auc"]) and one_class["accuracy"] == 0.5


@pytest.mark.parametrize("field, value", [
    ("epochs", 0), ("batch_size", True), ("learning_rate", 0.0), ("loss", "mse"),
    ("core_k", 0), ("core_k", 513), ("core_method", "map"), ("heldout_trials", -2),
])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        pretrain.PretrainConfig(**{field: value})


# ----------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def pretrained(tiny_dataset, tmp_path_factory):
    """CONFIG trained into a fresh directory; the checkpoint after epoch 1 is kept aside."""
    _, data_dir = tiny_dataset
    out = tmp_path_factory.mktemp("theta0")
    aside = tmp_path_factory.mktemp("aside") / "checkpoint_epoch1.npz"
    real = io.save_npz

    def save_and_copy(path, **arrays):
        real(path, **arrays)
        if str(path).endswith("checkpoint.npz") and int(arrays["epoch"]) == 1:
            shutil.copy(path, aside)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(io, "save_npz", save_and_copy)
        manifest = pretrain.pretrain(data_dir, CONFIG, out, progress=False,
                                     log=lambda *_: None)
    assert aside.exists()
    return data_dir, out, manifest, aside


def _checkpoint_params(path, template):
    saved = io.load_npz(path)
    leaves = [saved[f"p{i}"] for i in range(len(jax.tree.leaves(template)))]
    return jax.tree.unflatten(jax.tree.structure(template), leaves)


def _assert_same_tree(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_pretrain_writes_artefacts_that_load_back(pretrained):
    data_dir, out, manifest, _ = pretrained
    for f in ("theta0.msgpack", "core_set.npz", "manifest.json", "checkpoint.npz",
              "history.json", "metrics.json"):
        assert (out / f).exists(), f
    theta0 = artifacts.load_theta0(out)
    assert theta0.manifest["pretrain"] == json.loads(json.dumps(manifest["pretrain"]))
    assert len(theta0.fingerprint) == 16 and theta0.screen is None
    # the loaded params are the trained ones (the last checkpoint's)
    _assert_same_tree(theta0.params, _checkpoint_params(out / "checkpoint.npz",
                                                        theta0.params))
    assert [h["epoch"] for h in manifest["history"]] == [1, 2]
    # the core sets: k distinct D0 grasps, their labels those of D0
    _, data = dataset.load(data_dir)
    ctx, slot = np.nonzero(data["valid"])
    d0_label = data["label"][ctx, slot].astype(np.float32)
    for kind in ("dpp", "random"):
        idx = theta0.core[f"{kind}_index"]
        assert len(np.unique(idx)) == CONFIG.core_k
        np.testing.assert_array_equal(theta0.core[f"{kind}_label"], d0_label[idx])
        rows = artifacts.core_set_data(kind, theta0)
        assert rows.image.shape == (CONFIG.core_k, 32, 32) and rows.weight.sum() == 4
    assert artifacts.core_set_data("none", theta0).image.shape[0] == 0
    # held-out metrics are reported for 1 object x 1 pose x 64 grasps
    assert manifest["heldout"]["n"] == 64
    assert 0.0 <= manifest["heldout"]["accuracy"] <= 1.0
    # the network scores crops in [0, 1]
    p = theta0.network.apply(theta0.params, rows.image, rows.depth)
    assert np.all((np.asarray(p) >= 0) & (np.asarray(p) <= 1))


def test_pretrain_resumes_from_checkpoint_to_same_params(pretrained, tmp_path):
    data_dir, out, _, aside = pretrained
    shutil.copy(aside, tmp_path / "checkpoint.npz")  # stopped after epoch 1 of 2
    lines = []
    pretrain.pretrain(data_dir, CONFIG, tmp_path, progress=False, log=lines.append)
    assert any("resuming at epoch 1" in line for line in lines)
    artifacts._load.cache_clear()
    _assert_same_tree(artifacts.load_theta0(tmp_path).params,
                      artifacts.load_theta0(out).params)
    np.testing.assert_array_equal(io.load_npz(tmp_path / "core_set.npz")["dpp_index"],
                                  io.load_npz(out / "core_set.npz")["dpp_index"])


def test_pretrain_refuses_another_run_in_same_dir(pretrained):
    data_dir, out, _, _ = pretrained
    other = pretrain.PretrainConfig(**{**CONFIG.__dict__, "seed": 1})
    with pytest.raises(ValueError, match="another pretraining run"):
        pretrain.pretrain(data_dir, other, out, progress=False, log=lambda *_: None)


def test_pretrain_core_k_larger_than_data_is_refused(tiny_dataset, tmp_path):
    _, data_dir = tiny_dataset
    config = pretrain.PretrainConfig(epochs=1, batch_size=256, heldout_objects=1,
                                     heldout_poses=1, heldout_trials=1, core_k=500)
    with pytest.raises(ValueError, match="exceeds"):
        pretrain.pretrain(data_dir, config, tmp_path / "out", progress=False,
                          log=lambda *_: None)
    assert not (tmp_path / "out").exists()  # refused before anything is written


def test_pretrain_batch_larger_than_data_is_refused_before_writing(tiny_dataset, tmp_path):
    _, data_dir = tiny_dataset
    config = pretrain.PretrainConfig(epochs=1, batch_size=100_000, heldout_objects=1,
                                     heldout_poses=1, heldout_trials=1, core_k=4)
    with pytest.raises(ValueError, match="--batch-size 100000"):
        pretrain.pretrain(data_dir, config, tmp_path / "out", progress=False,
                          log=lambda *_: None)
    assert not (tmp_path / "out").exists()


def _damage(path, how):
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                      "random": np.random.default_rng(0).bytes(len(data))}[how])


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_damaged_checkpoint_is_one_line_naming_it(pretrained, tmp_path, how):
    data_dir, _, _, aside = pretrained
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(aside, out / "checkpoint.npz")
    _damage(out / "checkpoint.npz", how)
    with pytest.raises(io.DamagedFileError) as info:
        pretrain.pretrain(data_dir, CONFIG, out, progress=False, log=lambda *_: None)
    msg = str(info.value)
    assert "\n" not in msg and str(out / "checkpoint.npz") in msg and "delete it" in msg
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.npz"]  # nothing written


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_pretrain_on_damaged_data_names_the_shard(tiny_dataset, tmp_path, how):
    _, first = tiny_dataset
    data_dir = tmp_path / "d0"
    shutil.copytree(first, data_dir)
    _damage(data_dir / "shard_00000.npz", how)
    with pytest.raises(io.DamagedFileError) as info:
        pretrain.pretrain(data_dir, CONFIG, tmp_path / "out", progress=False,
                          log=lambda *_: None)
    msg = str(info.value)
    assert "\n" not in msg and "shard_00000.npz" in msg and "sern grasp dataset" in msg
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- screen


def test_screen_rows_follow_the_stated_rule(tiny_theta0):
    rows = pretrain.screen(tiny_theta0.network, tiny_theta0.params,
                           [objects.make_object("small_box")], num_poses=1, num_trials=2,
                           progress=False)
    assert len(rows) == 1
    for r in rows:
        # the best candidate is valued on fresh trials (tests/grasp/test_screen_debiased.py)
        assert r["hard"] == (r["greedy_success"] <= 0.6 and r["best_success_fresh"] >= 0.8)
        assert 0 <= r["greedy_success"] <= r["best_success"] <= 1
        assert r["mean_success"] <= r["best_success"]


def test_screen_rule_at_its_boundaries(monkeypatch, tiny_theta0):
    cases = [(0.6, 0.8, True), (0.61, 0.9, False), (0.2, 0.79, False), (0.0, 1.0, True)]
    fake = [{"object": f"o{i}", "greedy_success": g, "best_success": b}
            for i, (g, b, _) in enumerate(cases)]
    monkeypatch.setattr(pretrain, "_evaluate_objects", lambda *a, **k: ([], [], [], fake))
    rows = pretrain.screen(tiny_theta0.network, tiny_theta0.params, [], progress=False)
    assert [r["hard"] for r in rows] == [c[2] for c in cases]


# ----------------------------------------------------------------------------- artefacts


def test_hard_set_prefers_rule_then_lowest_greedy(tiny_theta0):
    screen = {"objects": [
        {"object": "a", "greedy_success": 0.5, "best_success": 0.9, "hard": True},
        {"object": "b", "greedy_success": 0.7, "best_success": 0.9, "hard": False},
        {"object": "c", "greedy_success": 0.1, "best_success": 0.5, "hard": False},
        {"object": "d", "greedy_success": 0.65, "best_success": 0.8, "hard": False},
        {"object": "e", "greedy_success": 0.3, "best_success": 1.0, "hard": True},
    ]}
    hs = artifacts.hard_set(tiny_theta0._replace(screen=screen), num=3)
    assert hs["objects"] == ["e", "a", "d"]  # c: nothing to learn (best < 0.8)
    assert hs["meets_rule"] == [True, True, False]
    with pytest.raises(ValueError, match="no screen"):
        artifacts.hard_set(tiny_theta0)


def test_load_and_install_errors(pretrained, tmp_path):
    _, out, _, _ = pretrained
    with pytest.raises(ValueError, match="no pretrained network"):
        artifacts.load_theta0(tmp_path)
    with pytest.raises(ValueError, match="screen.json"):  # a pretrain dir before the screen
        artifacts.install(out, tmp_path / "dst")
    with pytest.raises(ValueError, match="core set"):
        artifacts.core_set_data("dpp2", artifacts.load_theta0(out))
    # a θ0 file that does not match its manifest is refused
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    blob = bytearray((broken / "theta0.msgpack").read_bytes())
    blob[-1] ^= 1
    (broken / "theta0.msgpack").write_bytes(bytes(blob))
    with pytest.raises(ValueError, match="does not match its manifest"):
        artifacts.load_theta0(broken)


def test_install_copies_and_reloads(pretrained, tmp_path):
    _, out, _, _ = pretrained
    src = tmp_path / "src"
    shutil.copytree(out, src)
    io.save_json(src / "screen.json", {"rule": pretrain.HARD_RULE, "objects": []})
    dst = artifacts.install(src, tmp_path / "dst")
    theta0 = artifacts.load_theta0(dst)
    assert theta0.screen == {"rule": pretrain.HARD_RULE, "objects": []}
    assert theta0.fingerprint == artifacts.load_theta0(out).fingerprint


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
@pytest.mark.parametrize("name", ["core_set.npz", "theta0.msgpack"])
def test_damaged_theta0_files_are_one_line(pretrained, tmp_path, name, how):
    from sern_jax.grasp.model import artifacts

    _, out, _, _ = pretrained
    copy = tmp_path / "theta0"
    shutil.copytree(out, copy)
    _damage(copy / name, how)
    if name == "theta0.msgpack":  # the msgpack's own check, not the manifest's digest
        import hashlib

        manifest = json.loads((copy / "manifest.json").read_text())
        manifest["theta0_sha256"] = hashlib.sha256((copy / name).read_bytes()).hexdigest()
        (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError) as info:
        artifacts.load_theta0(copy)
    msg = str(info.value)
    assert "\n" not in msg and str(copy / name) in msg and "--theta0" in msg
