"""Pretraining θ0 on D0, its held-out evaluation, and the DPP core set.

``pretrain(data_dir, config, out_dir)``:

1. crops every labelled grasp of D0 (``crops.extract_batch``; crops are not stored in D0);
2. fits the input normaliser on the training objects and trains the quality network with
   Adam on binary cross-entropy (the default; ``loss="l1"`` is the printed Algorithm 1's
   loss, a negative control), minibatches drawn by a seeded permutation per epoch, a
   checkpoint after every epoch (an interrupted run resumes at the last finished epoch);
3. evaluates on objects never seen in training (the same procedural population with another
   seed): ROC-AUC and accuracy against single-trial outcomes, and calibration (reliability
   diagram, ECE) against success frequencies from ``heldout_trials`` trials per grasp;
4. chooses the core set C: features (the network's penultimate layer) of every D0 grasp,
   lifted by random Fourier features, k = 172 drawn by an exact k-DPP (``dpp``), plus k
   uniformly random grasps for the ablation.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Callable

import jax
import numpy as np
import optax

from sern_jax.core import dpp
from sern_jax.infra import io
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.world import crops as crops_lib
from sern_jax.grasp.model import dataset as dataset_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.model import quality_net as qn
from sern_jax.grasp.world import scene as scene_lib
from sern_jax.grasp.world import sim as sim_lib

__all__ = [
    "PretrainConfig",
    "crops_of",
    "pretrain",
    "evaluate",
    "classification_metrics",
    "HELDOUT_SEED_OFFSET",
    "HARD_RULE",
    "is_hard",
    "best_candidate_estimates",
    "best_candidate_lcb",
    "HARD_RULES",
    "LCB_LEVEL",
    "screen",
]

HELDOUT_SEED_OFFSET = 1_000_003  # held-out population seed = D0 seed + this
CORE_RFF = 512  # random Fourier features of the core set's k-DPP (dpp.select_core_set)


@dataclasses.dataclass(frozen=True)
class PretrainConfig:
    """Training, evaluation and core-set settings of ``sern grasp pretrain``."""

    epochs: int = 8
    batch_size: int = 128
    learning_rate: float = 1e-3
    loss: str = "bce"
    seed: int = 0
    heldout_objects: int = 12
    heldout_poses: int = 4
    heldout_trials: int = 16
    core_k: int = 172
    core_method: str = "sample"

    def __post_init__(self):
        for name in ("epochs", "batch_size", "heldout_objects", "heldout_poses",
                     "heldout_trials", "core_k"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if not (np.isfinite(self.learning_rate) and self.learning_rate > 0):
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate!r}")
        if self.loss not in qn.LOSSES:
            raise ValueError(f"loss must be one of {sorted(qn.LOSSES)}, got {self.loss!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or not 0 <= self.seed < 2**31:
            raise ValueError(f"seed must be an integer in [0, 2**31), got {self.seed!r}")
        if self.core_method not in ("sample", "greedy"):
            raise ValueError(f"core_method must be sample or greedy, got {self.core_method!r}")
        if self.core_k > CORE_RFF:  # the k-DPP's lifted kernel has rank CORE_RFF
            raise ValueError(f"core_k must be <= {CORE_RFF} (the rank of the k-DPP's random-"
                             f"feature kernel), got {self.core_k}")

    def fingerprint(self, data_fingerprint: str) -> str:
        d = dataclasses.asdict(self)
        d["data"] = data_fingerprint
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


_CROP = jax.jit(lambda d, c, a, g: crops_lib.extract_batch(d, (c, a, g)))


def crops_of(arrays: dict[str, np.ndarray], chunk: int = 256):
    """Crops of every valid candidate of a dataset's contexts.

    Returns (image [n, S, S] float32, depth [n], context [n] index, slot [n] index), in
    context-major order of the valid slots.
    """
    valid = arrays["valid"]
    images, depths = [], []
    num = len(valid)
    for lo in range(0, num, chunk):
        hi = min(lo + chunk, num)
        # pad the last chunk to the fixed shape: one compile
        pad = chunk - (hi - lo)
        sl = lambda a: np.concatenate([a[lo:hi], np.repeat(a[hi - 1:hi], pad, 0)])  # noqa: E731
        c = _CROP(sl(arrays["depth"]), sl(arrays["center_px"]), sl(arrays["angle_px"]),
                  sl(arrays["grasp_depth"]))
        v = valid[lo:hi]
        images.append(np.asarray(c.image)[: hi - lo][v])
        depths.append(np.asarray(c.depth)[: hi - lo][v])
    ctx, slot = np.nonzero(valid)
    return np.concatenate(images), np.concatenate(depths), ctx, slot


def classification_metrics(prob: np.ndarray, label: np.ndarray,
                           freq: np.ndarray | None = None, bins: int = 10) -> dict:
    """Accuracy and ROC-AUC against 0/1 outcomes; calibration against frequencies.

    Args:
      prob: [n] predicted P(success).
      label: [n] single-trial outcomes (0/1).
      freq: optional [n] success frequencies from many trials (the calibration target;
        defaults to ``label``).
      bins: equal-width bins of the reliability diagram.

    Returns:
      dict with accuracy, roc_auc (Mann-Whitney, ties counted half), positive_rate, brier,
      ece, and the reliability diagram (per bin: count, mean prediction, mean frequency).
    """
    prob = np.asarray(prob, np.float64)
    label = np.asarray(label).astype(bool)
    target = label.astype(np.float64) if freq is None else np.asarray(freq, np.float64)
    if len(prob) == 0:  # e.g. no validation objects (fewer than 10 in D0): NaN, no warnings
        nan = float("nan")
        return {"n": 0, "accuracy": nan, "accuracy_majority_class": nan, "roc_auc": nan,
                "positive_rate": nan, "brier": nan, "ece": nan, "reliability": []}
    pos, neg = prob[label], prob[~label]
    if len(pos) and len(neg):
        order = np.argsort(np.concatenate([pos, neg]), kind="mergesort")
        ranks = np.empty(len(order))
        values = np.concatenate([pos, neg])[order]
        # average ranks over ties
        uniq, start, counts = np.unique(values, return_index=True, return_counts=True)
        avg = start + (counts + 1) / 2.0
        ranks[order] = np.repeat(avg, counts)
        auc = (ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg))
    else:
        auc = float("nan")
    edges = np.linspace(0, 1, bins + 1)
    which = np.clip(np.digitize(prob, edges) - 1, 0, bins - 1)
    diagram, ece = [], 0.0
    for b in range(bins):
        m = which == b
        if m.any():
            conf, acc = float(prob[m].mean()), float(target[m].mean())
            ece += m.mean() * abs(conf - acc)
            diagram.append({"bin": [float(edges[b]), float(edges[b + 1])],
                            "count": int(m.sum()), "mean_prediction": conf,
                            "mean_frequency": acc})
    return {
        "n": int(len(prob)),
        "accuracy": float(np.mean((prob >= 0.5) == label)),
        "accuracy_majority_class": float(max(label.mean(), 1 - label.mean())),
        "roc_auc": float(auc),
        "positive_rate": float(label.mean()),
        "brier": float(np.mean((prob - target) ** 2)),
        "ece": float(ece),
        "reliability": diagram,
    }


def _predict(network, params, image, depth, chunk: int = 4096, what: str = "apply"):
    """``network.apply`` (or ``what``, e.g. ``"features"``) over rows in fixed-size chunks,
    the last one zero-padded, so every call reuses one compile."""
    fn = _predict_fn(network, what)
    out = []
    for lo in range(0, len(image), chunk):
        hi = min(lo + chunk, len(image))
        pad = chunk - (hi - lo)
        im = np.concatenate([image[lo:hi], np.zeros((pad,) + image.shape[1:], image.dtype)])
        de = np.concatenate([depth[lo:hi], np.zeros(pad, depth.dtype)])
        out.append(np.asarray(fn(params, im, de))[: hi - lo])
    return np.concatenate(out) if out else np.zeros(0)


_PREDICT_FNS: dict = {}


def _predict_fn(network, what: str = "apply"):
    key = (network.config, what)
    if key not in _PREDICT_FNS:
        _PREDICT_FNS[key] = jax.jit(getattr(network, what))
    return _PREDICT_FNS[key]


def _features(network, params, image, depth, chunk: int = 4096) -> np.ndarray:
    return _predict(network, params, image, depth, chunk, what="features")


FRESH_STREAM = 2  # fold_in id (beside dataset's CONTEXT / TRIAL streams): fresh trials


def _fresh_best(key, spec, lc, num_trials, num_fresh, backend):
    """[P] success frequency of each pose's best candidate (argmax of ``lc``'s
    frequencies; the first of ties) over ``num_fresh`` new trials, independent of the
    trials that chose it (noise ``fold_in(key, FRESH_STREAM)``); NaN without a valid one."""
    from sern_jax.grasp.world import context as context_lib
    from sern_jax.grasp.world import sim as sim_lib

    has = lc.valid.any(1)
    out = np.full(len(has), np.nan)
    if not has.any():
        return out
    pick = np.argmax(np.where(lc.valid, lc.successes, -1), axis=1)
    p_i = np.flatnonzero(has)
    model = context_lib.scene_model(spec, context_lib.ContextConfig(renderer="native"))
    simulator = sim_lib.GraspSimulator(model, backend=backend)
    noise = sim_lib.sample_noise(jax.random.fold_in(key, FRESH_STREAM),
                                 len(p_i) * num_fresh, simulator.config)
    res = simulator.run_trials(
        np.repeat(np.asarray(lc.grasps, np.float64)[p_i, pick[p_i]], num_fresh, axis=0),
        noise, object_pose=np.repeat(np.asarray(lc.pose)[p_i], num_fresh, axis=0))
    out[p_i] = res.success.reshape(len(p_i), num_fresh).mean(1)
    return out


def best_candidate_estimates(select, valid, fresh) -> dict:
    """The best candidate's success, biased and debiased, averaged over poses.

    Args:
      select: [P, K] success frequencies of the screening trials.
      valid: [P, K] bool.
      fresh: [P] success frequency of each pose's chosen best candidate (the argmax of
        ``select``) over trials independent of ``select`` (NaN: no valid candidate).

    Returns:
      ``best_success``: mean over poses of max_k select (biased upward: the largest of K
      noisy frequencies); ``best_success_fresh``: mean of ``fresh`` (unbiased for the
      chosen candidate's true success, which is at most the best's).
    """
    select = np.where(valid, select, -1.0)
    return {"best_success": float(select.max(1).mean()),
            "best_success_fresh": float(np.nanmean(fresh)) if np.isfinite(fresh).any()
            else 0.0}


LCB_LEVEL = 0.95
HARD_RULES = ("fresh", "lcb")


def best_candidate_lcb(successes, trials, valid, level: float = LCB_LEVEL) -> dict:
    """A lower confidence bound on the best candidate's success from the screening trials
    alone (the alternative to valuing it on fresh trials).

    Every valid (pose, candidate) gets a one-sided Clopper–Pearson lower bound at level
    1 − (1 − level)/N, N the number of valid pairs (Bonferroni), so with probability at
    least ``level`` all N bounds hold at once; then each pose's largest bound is at most
    that pose's best true success (max_k LCB_k <= max_k r_k), and their mean over poses is
    a lower bound on the mean best success. The price of choosing among N: a candidate
    that succeeds in all of its m trials gets the bound ((1 − level)/N)^(1/m), e.g. 0.32 at
    m = 8 and N = 8 × 64, so with 8 screening trials no object can reach 0.8 this way
    (m >= 42 is needed for a perfect candidate); the fresh-trial rule has no such cost.

    Args:
      successes: [P, K] successes of each candidate (integers).
      trials: trials per candidate (int or [P, K]).
      valid: [P, K] bool.
      level: simultaneous confidence level.

    Returns:
      ``best_success_lcb`` (mean over poses with a valid candidate of max_k LCB_k; 0.0 if
      none) and ``lcb_level``.
    """
    from scipy import stats as sps

    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    valid = np.asarray(valid, bool)
    k, m = np.broadcast_arrays(np.asarray(successes, np.float64),
                               np.asarray(trials, np.float64))
    if np.any(m[valid] < 1) or np.any(k[valid] < 0) or np.any(k[valid] > m[valid]):
        raise ValueError("need 0 <= successes <= trials and trials >= 1 on valid candidates")
    n_pairs = int(valid.sum())
    if n_pairs == 0:
        return {"best_success_lcb": 0.0, "lcb_level": float(level)}
    alpha = (1.0 - level) / n_pairs
    with np.errstate(invalid="ignore"):
        lower = np.where(k > 0, sps.beta.ppf(alpha, np.maximum(k, 1), m - k + 1), 0.0)
    lower = np.where(valid, lower, -np.inf).max(1)
    return {"best_success_lcb": float(lower[np.isfinite(lower)].mean()),
            "lcb_level": float(level)}


def is_hard(row: dict, rule: str = "fresh") -> bool:
    """The hard-set rule on a screen row: θ0's greedy success <= 60 % and the best
    candidate's success >= 80 %, the best valued by ``rule``: ``"fresh"`` (default) the
    chosen best candidate's success on fresh trials (``best_success`` where a row predates
    the fresh trials); ``"lcb"`` the simultaneous lower confidence bound of
    :func:`best_candidate_lcb` (``best_success_lcb``)."""
    if rule == "fresh":
        best = row.get("best_success_fresh", row["best_success"])
    elif rule == "lcb":
        if "best_success_lcb" not in row:
            raise ValueError("this screen row has no best_success_lcb: re-run the screen")
        best = row["best_success_lcb"]
    else:
        raise ValueError(f"rule must be one of {HARD_RULES}, got {rule!r}")
    return bool(row["greedy_success"] <= HARD_RULE["max_greedy_success"]
                and best >= HARD_RULE["min_best_success"])


def _evaluate_objects(network, params, specs, root, num_poses, num_trials, backend,
                      progress, desc, fresh_trials: int = 0):
    """Predictions against outcomes on ``specs``: (probs, labels, freqs, per-object rows).
    ``fresh_trials`` > 0 values each pose's best candidate on that many new trials."""
    from tqdm.auto import tqdm

    probs, labels, freqs, per_object = [], [], [], []
    for i, spec in enumerate(tqdm(specs, desc=desc, unit="obj", disable=not progress)):
        key_i = jax.random.fold_in(root, i)
        lc = dataset_lib.label_contexts(key_i, spec, num_poses, num_trials, backend)
        arrays = {f: getattr(lc, f) for f in ("depth", "center_px", "angle_px",
                                               "grasp_depth", "valid")}
        image, depth, ctx, slot = crops_of(arrays)
        p = _predict(network, params, image, depth)
        probs.append(p)
        labels.append(lc.label[ctx, slot])
        freqs.append(lc.successes[ctx, slot] / num_trials)
        # the greedy choice of each pose against the best candidate of that pose
        score = np.full(lc.valid.shape, -np.inf)
        score[ctx, slot] = p
        greedy = np.argmax(score, axis=1)
        freq_all = np.where(lc.valid, lc.successes / num_trials, -1.0)
        rows = np.arange(len(greedy))
        row = {
            "object": spec.name,
            "greedy_success": float(freq_all[rows, greedy].mean()),
            "best_success": float(freq_all.max(1).mean()),
            "mean_success": float(freqs[-1].mean()),
            "candidate_success_quartiles": [float(q) for q in
                                            np.percentile(freqs[-1], [25, 50, 75])],
            "valid_per_pose": float(lc.valid.sum(1).mean()),
            "poses": int(num_poses),
            "trials": int(num_trials),
        }
        if fresh_trials:
            row.update(best_candidate_lcb(lc.successes, num_trials, lc.valid))
            fresh = _fresh_best(key_i, spec, lc, num_trials, fresh_trials, backend)
            row.update(best_candidate_estimates(lc.successes / num_trials, lc.valid, fresh))
            row["fresh_trials"] = int(fresh_trials)
            row["best_fresh_per_pose"] = [None if not np.isfinite(v) else float(v)
                                          for v in fresh]
        per_object.append(row)
    return probs, labels, freqs, per_object


def evaluate(network, params, data_seed: int, config: PretrainConfig,
             backend: str = "native", progress: bool = True) -> dict:
    """Held-out metrics of ``params`` on objects never seen in training.

    The held-out objects are ``objects.sample_population(data_seed + HELDOUT_SEED_OFFSET,
    heldout_objects)``: the same procedural families as D0, other shapes and sizes.
    """
    seed = data_seed + HELDOUT_SEED_OFFSET
    specs = objects_lib.sample_population(seed, config.heldout_objects)
    probs, labels, freqs, per_object = _evaluate_objects(
        network, params, specs, jax.random.key(seed), config.heldout_poses,
        config.heldout_trials, backend, progress, "held-out")
    metrics = classification_metrics(np.concatenate(probs), np.concatenate(labels),
                                     np.concatenate(freqs))
    metrics["objects"] = per_object
    metrics["heldout_seed"] = seed
    return metrics


HARD_RULE = {"max_greedy_success": 0.6, "min_best_success": 0.8,
             "best_valued_on": "fresh trials independent of those that chose it"}


def screen(network, params, specs, num_poses: int = 8, num_trials: int = 16, seed: int = 0,
           backend: str = "native", progress: bool = True,
           fresh_trials: int | None = None, rule: str = "fresh") -> list[dict]:
    """The hard-set rule on each object: θ0's greedy success and the best candidate's.

    An object is *hard* (``row["hard"]``) when, averaged over ``num_poses`` random resting
    poses, θ0's greedy choice succeeds at most 60 % of the time while the best of the 64
    candidates succeeds at least 80 % of the time (success frequencies over ``num_trials``
    trials): θ0 grasps it poorly and there is something to learn. This is how the paper
    picked its meshes ("hardly grasped by the pretrained model"), made a stated rule.

    The best candidate is chosen on the screening trials and valued on ``fresh_trials``
    new, independent trials (default: as many as ``num_trials``): the maximum of 64 noisy
    frequencies is biased upward (64 candidates of true success 0.4 estimated from 8 trials
    each show a maximum of about 0.8). ``best_success`` keeps the biased maximum for
    comparison; the rule (:func:`is_hard`) uses ``best_success_fresh``. With
    ``rule="lcb"`` it uses instead ``best_success_lcb``, a simultaneous 95 % lower
    confidence bound from the screening trials alone (:func:`best_candidate_lcb`; every
    row carries it, and ``hard_rule`` names the rule that set ``hard``).
    """
    fresh = num_trials if fresh_trials is None else fresh_trials
    if fresh < 1:
        raise ValueError(f"fresh_trials must be >= 1, got {fresh}")
    if rule not in HARD_RULES:
        raise ValueError(f"rule must be one of {HARD_RULES}, got {rule!r}")
    *_, rows = _evaluate_objects(network, params, specs, jax.random.key(seed), num_poses,
                                 num_trials, backend, progress, "screen", fresh_trials=fresh)
    for row in rows:
        row["hard"] = is_hard(row, rule)
        row["hard_rule"] = rule
    return rows


def pretrain(
    data_dir: str | Path,
    config: PretrainConfig,
    out_dir: str | Path,
    *,
    network_config: qn.QualityNetConfig = qn.QualityNetConfig(),
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict:
    """Trains θ0 on D0, evaluates it on held-out objects and picks the core sets.

    Writes into ``out_dir``: ``checkpoint.npz`` (after each epoch; resumes), ``history.json``,
    ``metrics.json`` and the artefacts of :mod:`artifacts` (``theta0.msgpack``,
    ``core_set.npz``, ``manifest.json``). Returns the manifest.

    D0's shards and the checkpoint are verified on load (``io.load_npz``): a damaged file is
    refused in one line naming it. ``out_dir`` is locked (``io.run_lock``) while this runs.
    """
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    data_config, arrays = dataset_lib.load(data_dir)  # every shard verified (one-line errors)
    fingerprint = config.fingerprint(data_config.fingerprint())
    ckpt = out_dir / "checkpoint.npz"
    _check_checkpoint(ckpt, fingerprint, out_dir)
    # sizes that depend on the data, before any crop or compile
    num_grasps = int(arrays["valid"].sum())
    # validation split by object (every 10th object), for the training curve only
    val = arrays["object_index"][np.nonzero(arrays["valid"])[0]] % 10 == 9
    tr = ~val
    if config.core_k > num_grasps:
        raise ValueError(f"--core-k {config.core_k} exceeds D0's {num_grasps} labelled grasps")
    if int(tr.sum()) < config.batch_size:
        raise ValueError(f"--batch-size {config.batch_size}: D0 has {int(tr.sum())} training "
                         "grasps, fewer than one batch")
    with io.run_lock(out_dir):
        _check_checkpoint(ckpt, fingerprint, out_dir)  # again, under the lock
        return _pretrain(config, data_config, arrays, out_dir, ckpt, fingerprint, val, tr,
                         network_config, progress, log, t_start)


def _check_checkpoint(ckpt: Path, fingerprint: str, out_dir: Path) -> None:
    if not ckpt.exists():
        return
    saved = io.load_npz(ckpt, advice="delete it to restart pretraining from epoch 0")
    if str(saved.get("fingerprint")) != fingerprint:
        raise ValueError(f"{out_dir} holds another pretraining run; choose another --out "
                         "or delete it")


def _pretrain(config, data_config, arrays, out_dir, ckpt, fingerprint, val, tr,
              network_config, progress, log, t_start) -> dict:
    from tqdm.auto import tqdm

    t = time.perf_counter()
    image, depth, ctx, slot = crops_of(arrays)
    label = arrays["label"][ctx, slot].astype(np.float32)
    log(f"D0: {len(label):,} labelled grasps from {data_config.num_objects} objects "
        f"({label.mean():.1%} successes); crops in {time.perf_counter() - t:.1f} s")
    network = qn.make_quality_network(network_config)
    normalizer = qn.fit_normalizer(image[tr], depth[tr])
    key = jax.random.key(config.seed)
    params = network.init(jax.random.fold_in(key, 0), normalizer)
    optimizer = optax.adam(config.learning_rate)
    opt_state = qn.init_opt_state(optimizer, params)
    step = jax.jit(qn.make_train_step(network, optimizer, config.loss))
    history, start_epoch = [], 0
    if ckpt.exists():
        saved = io.load_npz(ckpt, advice="delete it to restart pretraining from epoch 0")
        params = artifacts.tree_from_arrays(saved, params, "p")
        opt_state = artifacts.tree_from_arrays(saved, opt_state, "o")
        history = json.loads(str(saved["history"]))
        start_epoch = int(saved["epoch"])
        log(f"resuming at epoch {start_epoch}")

    idx_tr = np.flatnonzero(tr)
    bs = config.batch_size
    steps = len(idx_tr) // bs  # >= 1: checked before the lock
    ones = np.ones(bs, np.float32)
    for epoch in range(start_epoch, config.epochs):
        t = time.perf_counter()
        perm = np.asarray(jax.random.permutation(jax.random.fold_in(key, 1000 + epoch),
                                                 len(idx_tr)))
        order = idx_tr[perm]
        losses = []
        for b in tqdm(range(steps), desc=f"epoch {epoch + 1}/{config.epochs}", unit="step",
                      disable=not progress, leave=False):
            sel = order[b * bs:(b + 1) * bs]
            params, opt_state, loss = step(
                params, opt_state, qn.TrainData(image[sel], depth[sel], label[sel], ones))
            losses.append(loss)
        train_loss = float(np.mean(jax.device_get(losses)))
        pv = _predict(network, params, image[val], depth[val])
        vm = classification_metrics(pv, label[val] > 0.5)
        history.append({"epoch": epoch + 1, "train_loss": train_loss,
                        "val_accuracy": vm["accuracy"], "val_roc_auc": vm["roc_auc"],
                        "seconds": time.perf_counter() - t})
        log(f"epoch {epoch + 1}: train loss {train_loss:.4f}, validation accuracy "
            f"{vm['accuracy']:.3f}, AUC {vm['roc_auc']:.3f} ({time.perf_counter() - t:.0f} s)")
        arrays_ckpt = (artifacts.tree_arrays(params, "p")
                       | artifacts.tree_arrays(opt_state, "o"))
        io.save_npz(ckpt, fingerprint=np.asarray(fingerprint), epoch=np.asarray(epoch + 1),
                    history=np.asarray(json.dumps(history)), **arrays_ckpt)
    io.save_json(out_dir / "history.json", history)
    train_s = time.perf_counter() - t_start

    log("held-out evaluation ...")
    t = time.perf_counter()
    metrics = evaluate(network, params, data_config.seed, config, data_config.backend,
                       progress)
    eval_s = time.perf_counter() - t
    log(f"held-out: accuracy {metrics['accuracy']:.3f} (majority class "
        f"{metrics['accuracy_majority_class']:.3f}), ROC-AUC {metrics['roc_auc']:.3f}, "
        f"ECE {metrics['ece']:.3f} on {metrics['n']:,} grasps")

    t = time.perf_counter()
    feats = _features(network, params, image, depth)
    k = config.core_k  # <= len(feats): checked before training
    key_core = jax.random.fold_in(key, 2)
    with jax.enable_x64():
        dpp_idx = np.asarray(dpp.select_core_set(key_core, feats, k, method=config.core_method))
    rand_idx = np.sort(np.asarray(jax.random.choice(jax.random.fold_in(key, 3), len(feats),
                                                    (k,), replace=False)))
    core_s = time.perf_counter() - t
    log(f"core set: k = {k} of {len(feats):,} by k-DPP ({config.core_method}) in {core_s:.1f} s")
    core = {
        "dpp_image": image[dpp_idx], "dpp_depth": depth[dpp_idx], "dpp_label": label[dpp_idx],
        "dpp_index": dpp_idx,
        "random_image": image[rand_idx], "random_depth": depth[rand_idx],
        "random_label": label[rand_idx], "random_index": rand_idx,
    }
    manifest = {
        "made_by": "sern grasp dataset, then sern grasp pretrain",
        "dataset": {"config": dataclasses.asdict(data_config),
                    "fingerprint": data_config.fingerprint(),
                    "labelled_grasps": int(len(label)),
                    "positive_fraction": float(label.mean())},
        "pretrain": dataclasses.asdict(config),
        "gripper": scene_lib.GRIPPER,
        "physics": sim_lib.physics_settings(),  # the world D0 was labelled in
        "history": history,
        "heldout": {k2: v for k2, v in metrics.items() if k2 != "reliability"},
        "core_set": {"k": k, "method": config.core_method,
                     "dpp_positive_fraction": float(label[dpp_idx].mean()),
                     "random_positive_fraction": float(label[rand_idx].mean())},
        "params": qn.param_count(network_config),
        "flops_per_grasp": qn.flops_per_grasp(network_config),
        "seconds": {"train": train_s, "heldout": eval_s, "core_set": core_s},
        "git_commit": io.run_metadata()["git_commit"],
    }
    io.save_json(out_dir / "metrics.json", metrics)
    artifacts.save(out_dir, network, params, core, manifest)
    return manifest
