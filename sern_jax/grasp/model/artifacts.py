"""The shipped pretrained network θ0 and core set C: package data with a manifest.

``sern grasp pretrain --install`` writes, into ``sern_jax/grasp/data/``:

* ``theta0.msgpack``: the quality network's ``QualityParams`` (weights + input normaliser),
  flax serialisation;
* ``core_set.npz``: the k = 172 crops chosen by the DPP from D0 (``dpp_*`` arrays) and, for
  the ablation, k crops chosen uniformly at random (``random_*``), each with grasp depth and
  label, stored as float16 crops (a few hundred kB);
* ``manifest.json``: how they were made (command, seed, commit, D0 size, training settings,
  held-out metrics, the network config), so anyone can regenerate them, and the sha256 of
  ``theta0.msgpack`` (``theta0_sha256``) and of ``screen.json`` (``screen_sha256``);
* ``screen.json``: the hard-set screen made with this θ0 (:func:`save_screen` writes it and
  records its digest).

Every file is checked when read: θ0 and the screen against the manifest's digests, the core
sets against the digest their archive carries (``io.load_npz``). A θ0 directory whose manifest
lacks the digest of a file it holds is refused, as a damaged one is: its contents could not
be checked.

:func:`load_theta0` reads them (cached); a user needs no pretraining to start.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.infra import io
from sern_jax.grasp.model import quality_net as qn

__all__ = [
    "DATA_DIR",
    "Theta0",
    "save",
    "save_screen",
    "check_screen_digest",
    "load_theta0",
    "core_set_data",
    "CORE_SET_KINDS",
    "install",
    "hard_set",
    "tree_arrays",
    "tree_from_arrays",
]

DATA_DIR = Path(__file__).resolve().parents[1] / "data"  # sern_jax/grasp/data
THETA0_FILE = "theta0.msgpack"
CORE_FILE = "core_set.npz"
MANIFEST_FILE = "manifest.json"
SCREEN_FILE = "screen.json"
FILES = (THETA0_FILE, CORE_FILE, MANIFEST_FILE, SCREEN_FILE)
CORE_SET_KINDS = ("dpp", "random", "none")
HARD_BEST_FLOOR = 0.8  # = pretrain.HARD_RULE["min_best_success"] (pretrain imports this module)


class Theta0(NamedTuple):
    """A pretrained network and where it came from."""

    network: qn.QualityNetwork
    params: qn.QualityParams
    core: dict  # {"dpp_image" [k, S, S], "dpp_depth" [k], "dpp_label" [k], "random_*" ...}
    manifest: dict
    fingerprint: str  # sha256 of the serialised params (16 hex digits)
    screen: dict | None = None  # the hard-set screen made with this θ0 (screen.json)


def _config_from(manifest: dict, path: Path | None = None) -> qn.QualityNetConfig:
    fields = {f.name for f in dataclasses.fields(qn.QualityNetConfig)}
    raw = {k: (tuple(v) if isinstance(v, list) else v)
           for k, v in manifest["network_config"].items() if k in fields}
    try:
        config = qn.QualityNetConfig(**raw)
        hash(config)  # list-valued fields (unhashable) are a damaged manifest too
    except (TypeError, ValueError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{path or MANIFEST_FILE}: 'network_config' is not a quality "
                         f"network's ({first}); restore the θ0 directory") from None
    return config


_RESTORE = ("restore it (reinstall sern_jax, or rerun `sern grasp pretrain --install`), or "
            "pass another --theta0")
# screen.json rows: the fields the hard-set rule reads (pretrain.screen writes them)
_SCREEN_ROW = {"object": str, "greedy_success": (int, float), "best_success": (int, float),
               "hard": bool}


def read_manifest(path: str | Path) -> dict:
    """A θ0 ``manifest.json``, checked against its schema: a JSON object whose
    ``network_config`` is an object and whose ``theta0_sha256`` is the 64-hex-digit digest
    of ``theta0.msgpack`` (every θ0 carries one; a manifest without it is refused, as its
    weights could not be checked), as ``screen_sha256`` is of ``screen.json`` where there is
    one (:func:`check_screen_digest`). One line naming the file otherwise (``ValueError``)."""
    from sern_jax.infra import validate

    manifest = validate.read_json_object(
        path, {"network_config": dict, "theta0_sha256": str}, what="θ0 manifest",
        advice=_RESTORE)
    _sha256_field(manifest, "theta0_sha256", path)
    _sha256_field(manifest, "screen_sha256", path)
    return manifest


def _sha256_field(manifest: dict, key: str, path) -> str | None:
    """``manifest[key]`` when it is a sha256 digest (64 lower-case hex digits), None when
    absent; one line naming the file otherwise."""
    digest = manifest.get(key)
    if digest is None:
        return None
    if not isinstance(digest, str) or len(digest) != 64 or \
            any(c not in "0123456789abcdef" for c in digest):
        raise ValueError(f"{path}: {key!r} is not a sha256 digest (a damaged θ0 manifest); "
                         f"{_RESTORE}")
    return digest


def check_screen_digest(root: str | Path, manifest: dict) -> bool:
    """Checks ``root/screen.json`` against the manifest's ``screen_sha256``; True when the
    directory holds a screen. A screen without a recorded digest, a digest without its screen,
    or a screen whose bytes do not match is one line naming the file (``ValueError``)."""
    root = Path(root)
    digest = _sha256_field(manifest, "screen_sha256", root / MANIFEST_FILE)
    path = root / SCREEN_FILE
    if not path.exists():
        if digest is not None:
            raise ValueError(f"{path} is missing, but {root / MANIFEST_FILE} records its "
                             f"sha256; {_RESTORE}")
        return False
    if digest is None:
        raise ValueError(f"{path}: {root / MANIFEST_FILE} has no 'screen_sha256', so the "
                         f"screen cannot be checked (a damaged θ0 directory); {_RESTORE}")
    actual = hashlib.sha256(path.read_bytes()).hexdigest()
    if actual != digest:
        raise ValueError(f"{path} does not match its manifest (sha256 {actual[:16]} != "
                         f"{digest[:16]}); {_RESTORE}")
    return True


def read_screen(path: str | Path) -> dict:
    """A θ0 ``screen.json`` checked against its schema (an object whose ``objects`` is a
    list of rows with the fields :func:`hard_set` reads); one line naming the file
    otherwise (``ValueError``)."""
    from sern_jax.infra import validate

    screen = validate.read_json_object(path, {"objects": list}, what="θ0 screen",
                                       advice=_RESTORE)
    for i, row in enumerate(screen["objects"]):
        if not isinstance(row, dict):
            raise ValueError(f"{path}: row {i} of 'objects' is not an object (a damaged θ0 "
                             f"screen); {_RESTORE}")
        for key, types in _SCREEN_ROW.items():
            value = row.get(key)
            if not isinstance(value, types) or (isinstance(value, bool) and bool not in
                                                (types if isinstance(types, tuple)
                                                 else (types,))):
                raise ValueError(f"{path}: row {i} of 'objects' has no valid {key!r} (a "
                                 f"damaged θ0 screen); {_RESTORE}")
        fresh = row.get("best_success_fresh")
        if fresh is not None and (isinstance(fresh, bool) or not isinstance(fresh,
                                                                              (int, float))):
            raise ValueError(f"{path}: row {i} of 'objects' has no valid "
                             f"'best_success_fresh' (a damaged θ0 screen); {_RESTORE}")
    return screen


def save(
    out_dir: str | Path,
    network: qn.QualityNetwork,
    params: qn.QualityParams,
    core: dict[str, np.ndarray],
    manifest: dict,
) -> Path:
    """Writes θ0, the core sets and the manifest into ``out_dir`` (atomically, each)."""
    from flax import serialization

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    blob = serialization.to_bytes(jax.device_get(params))
    io.save_bytes(out_dir / THETA0_FILE, blob)
    stored = {k: (np.asarray(v, np.float16) if k.endswith("_image") else np.asarray(v))
              for k, v in core.items()}
    io.save_npz(out_dir / CORE_FILE, **stored)
    manifest = dict(manifest)
    manifest["network_config"] = dataclasses.asdict(network.config)
    manifest["theta0_sha256"] = hashlib.sha256(blob).hexdigest()
    io.save_json(out_dir / MANIFEST_FILE, manifest)
    return out_dir


def save_screen(theta_dir: str | Path, screen: dict) -> Path:
    """Writes ``screen`` as ``theta_dir/screen.json`` and records its sha256 in the
    directory's manifest (``screen_sha256``), each atomically; returns the screen's path.
    (A crash between the two leaves a screen the manifest does not vouch for: refused on
    load, until the screen is written again.)"""
    theta_dir = Path(theta_dir)
    path = theta_dir / SCREEN_FILE
    io.save_json(path, screen)
    manifest = read_manifest(theta_dir / MANIFEST_FILE)
    manifest["screen_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    io.save_json(theta_dir / MANIFEST_FILE, manifest)
    _load.cache_clear()
    return path


@functools.lru_cache(maxsize=4)
def _load(path: str) -> Theta0:
    from flax import serialization

    root = Path(path)
    missing = [f for f in (THETA0_FILE, CORE_FILE, MANIFEST_FILE) if not (root / f).exists()]
    if missing:
        raise ValueError(
            f"no pretrained network in {root} (missing {', '.join(missing)}); make one with "
            "`sern grasp dataset` then `sern grasp pretrain --install`")
    manifest = read_manifest(root / MANIFEST_FILE)
    network = qn.make_quality_network(_config_from(manifest, root / MANIFEST_FILE))
    blob = (root / THETA0_FILE).read_bytes()
    digest = hashlib.sha256(blob).hexdigest()
    if manifest["theta0_sha256"] != digest:  # every θ0 carries its digest, and it is checked
        raise ValueError(f"{root / THETA0_FILE} does not match its manifest (sha256 "
                         f"{digest[:16]} != {manifest['theta0_sha256'][:16]}); {_RESTORE}")
    template = network.init(jax.random.key(0))
    try:
        params = serialization.from_bytes(template, blob)
    except Exception as exc:  # noqa: BLE001 - msgpack/flax raise many types on bad bytes
        raise ValueError(f"{root / THETA0_FILE} is damaged ({type(exc).__name__}); restore "
                         "it (reinstall sern_jax, or rerun `sern grasp pretrain --install`), "
                         "or pass another --theta0") from None
    params = jax.tree.map(jnp.asarray, params)
    core = io.load_npz(root / CORE_FILE, advice="restore it (reinstall sern_jax, or rerun "
                       "`sern grasp pretrain --install`), or pass another --theta0")
    screen = read_screen(root / SCREEN_FILE) if check_screen_digest(root, manifest) else None
    return Theta0(network, params, core, manifest, digest[:16], screen)


def load_theta0(path: str | Path | None = None, *, flag: str = "--theta0") -> Theta0:
    """The pretrained θ0 and core sets (default: the package's shipped copy). A directory
    the user named (``path``) that holds no θ0 or a damaged one is one line naming ``flag``
    and the directory (``ValueError``)."""
    try:
        return _load(str(Path(path) if path is not None else DATA_DIR))
    except ValueError as exc:
        if path is None or str(exc).startswith(flag):
            raise
        raise ValueError(f"{flag} {path}: {exc}") from None


def core_set_data(kind: str, theta0: Theta0) -> qn.TrainData:
    """The core set C as training rows (weight 1 each); ``"none"`` gives zero rows."""
    if kind not in CORE_SET_KINDS:
        raise ValueError(f"core set must be one of {CORE_SET_KINDS}, got {kind!r}")
    if kind == "none":
        s = theta0.network.config.crop_size
        return qn.TrainData(np.zeros((0, s, s), np.float32), np.zeros(0, np.float32),
                            np.zeros(0, np.float32), np.zeros(0, np.float32))
    c = theta0.core
    image = np.asarray(c[f"{kind}_image"], np.float32)
    return qn.TrainData(image, np.asarray(c[f"{kind}_depth"], np.float32),
                        np.asarray(c[f"{kind}_label"], np.float32),
                        np.ones(len(image), np.float32))


def install(src_dir: str | Path, dst_dir: str | Path = DATA_DIR) -> Path:
    """Copies θ0, the core sets, the manifest and the screen from a pretrain run directory
    into ``dst_dir`` (default: the package data that ``load_theta0()`` reads).

    The installed manifest carries the screen's sha256: the source's, checked against its
    screen, or, where the source manifest has none (a screen written by the pretrain run
    beside it), the digest of the screen installed. The installed directory is then loaded
    (every digest checked) before this returns."""
    src, dst = Path(src_dir), Path(dst_dir)
    missing = [f for f in FILES if not (src / f).exists()]
    if missing:
        raise ValueError(f"{src} lacks {', '.join(missing)}: run `sern grasp pretrain` first")
    blobs = {f: (src / f).read_bytes() for f in FILES}
    manifest = read_manifest(src / MANIFEST_FILE)
    if hashlib.sha256(blobs[THETA0_FILE]).hexdigest() != manifest["theta0_sha256"]:
        raise ValueError(f"{src / THETA0_FILE} does not match its manifest; nothing installed")
    if manifest.get("screen_sha256") is None:
        manifest["screen_sha256"] = hashlib.sha256(blobs[SCREEN_FILE]).hexdigest()
        blobs[MANIFEST_FILE] = (json.dumps(io.to_jsonable(manifest), indent=2) +
                                "\n").encode()
    else:
        check_screen_digest(src, manifest)
    for f in FILES:
        io.save_bytes(dst / f, blobs[f])
    _load.cache_clear()
    _load(str(dst))
    return dst


def hard_set(theta0: Theta0, num: int = 6) -> dict:
    """The objects the online experiments use, from the screen shipped with θ0.

    The rule (``pretrain.HARD_RULE``, :func:`pretrain.is_hard`): θ0's greedy choice succeeds
    at most 60 % of the time while the chosen best candidate succeeds at least 80 % on fresh
    trials, independent of those that chose it. When fewer than ``num`` objects meet it,
    the set is filled with the objects of lowest θ0 greedy success among those whose best
    candidate succeeds at least 80 % on the fresh trials (so there is something to learn),
    and ``meets_rule`` says which ones are which. A screen made before the fresh trials
    (rows without ``best_success_fresh``) is read with its biased ``best_success``.

    Returns:
      {"objects": [names], "meets_rule": [bools], "rows": [screen rows of those objects]}.
    """
    if not theta0.screen:
        raise ValueError("this θ0 has no screen.json: run `sern grasp screen --json-out "
                         "DIR/screen.json` for its directory, or name the objects")
    floor = HARD_BEST_FLOOR
    rows = [r for r in theta0.screen["objects"]
            if r.get("best_success_fresh", r["best_success"]) >= floor]
    rows.sort(key=lambda r: (not r["hard"], r["greedy_success"], r["object"]))
    chosen = rows[:num]
    return {"objects": [r["object"] for r in chosen],
            "meets_rule": [bool(r["hard"]) for r in chosen], "rows": chosen}


def tree_arrays(tree, prefix: str) -> dict[str, np.ndarray]:
    """The leaves of ``tree`` as ``{f"{prefix}{i}": array}``: a pytree in a checkpoint npz
    (``online.run``, ``online.AskTell``, ``pretrain``; read back by :func:`tree_from_arrays`)."""
    return {f"{prefix}{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(tree))}


def tree_from_arrays(saved: dict, template, prefix: str):
    """The pytree of ``template``'s structure whose leaves :func:`tree_arrays` saved."""
    num = len(jax.tree.leaves(template))
    return jax.tree.unflatten(jax.tree.structure(template),
                              [jnp.asarray(saved[f"{prefix}{i}"]) for i in range(num)])
