"""Checkpoints: plain state dicts saved atomically, a JSON record beside, safe loading.

A checkpoint ``NAME.pt`` holds only tensors, numbers, strings and dicts/lists of them (model
state, optionally discriminator and optimiser states, step counters) plus its record as a JSON
string; ``NAME.json`` beside it repeats the record for people (model config with the
`LayoutSpec`, training config, camera intrinsics, metrics). Loading uses
``torch.load(weights_only=True)``: a pickled object or a truncated file is one `InputError`
naming the file, and no pickled code runs; the record is checked against its declared schema
(`network.checkpoint_schema`).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes, atomic_write_json, loads_json
from network.checkpoint_schema import check_record
from network.inference.decision import check_depth_offset, check_offsets
from network.model.config import ModelConfig
from network.model.net import MVRackLay

FORMAT = "mvracklay-checkpoint"
FORMAT_VERSION = 1


def json_path(path: str | os.PathLike) -> Path:
    return Path(path).with_suffix(".json")


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any], record: dict[str, Any]) -> None:
    """Write ``payload`` (state dicts, counters) with ``record`` embedded, then the JSON beside it."""
    path = Path(path)
    record = {"format": FORMAT, "format_version": FORMAT_VERSION, **record}
    text = json.dumps(record, sort_keys=True)
    buf = io.BytesIO()
    torch.save({**payload, "record_json": text}, buf)
    atomic_write_bytes(path, buf.getvalue())
    atomic_write_json(json_path(path), record)


#: record keys of the heads the rack depth is read from: a file with a new one loses its `rack_depth_offset`
RACK_DEPTH_HEADS = ("back_edges", "uprights")


def save_updated(
    path: str | os.PathLike,
    payload: dict[str, Any],
    record: dict[str, Any],
    weights: dict[str, torch.Tensor],
    drop: str | None = None,
    **entries: Any,
) -> None:
    """A loaded checkpoint (`load_checkpoint`) written to ``path`` with ``weights`` replacing or adding
    tensors (in the payload's float dtype; every old tensor under the prefix ``drop`` removed first) and the
    record's ``entries`` set."""
    state = {k: v for k, v in payload["model"].items() if drop is None or not k.startswith(drop)}
    dtype = next(v.dtype for v in state.values() if v.is_floating_point())
    state.update({k: (v.detach().to(dtype) if v.is_floating_point() else v) for k, v in weights.items()})
    record = {k: v for k, v in record.items() if k not in ("format", "format_version")}
    record.update(entries)
    save_checkpoint(path, {**{k: v for k, v in payload.items() if k != "record_json"}, "model": state}, record)


def save_with_head(
    path: str | os.PathLike,
    payload: dict[str, Any],
    record: dict[str, Any],
    cfg: ModelConfig,
    name: str,
    head: torch.nn.Module,
    key: str,
    info: dict[str, Any],
) -> None:
    """A loaded checkpoint written to ``path`` with a head fitted afterwards (the trunk untouched): its
    weights under ``name.`` (any old ones replaced, in the payload's float dtype), ``cfg`` as the model
    config and ``info`` in the record under ``key``."""
    if key in RACK_DEPTH_HEADS:
        record = {k: v for k, v in record.items() if k != "rack_depth_offset"}  # measured on the heads it replaces
    weights = {f"{name}.{k}": v for k, v in head.state_dict().items()}
    save_updated(path, payload, record, weights, drop=f"{name}.", model_config=cfg.to_dict(), **{key: info})


def first_sentence(e: BaseException) -> str:
    """An error's first sentence, whole (never cut mid-word): what a one-line message quotes of it."""
    text = " ".join(str(e).split())
    head = text.split(". ")[0].rstrip(".")
    return head or type(e).__name__


def torch_load(path: str | os.PathLike, what: str = "checkpoint") -> Any:
    """``torch.load(weights_only=True)`` of a file, each way it can be wrong said as one line naming it: a folder
    or a missing file, an empty file, bytes that are no PyTorch archive (text), pickled objects (refused, never
    run), a cut or damaged archive. ``what`` names the kind of file in the messages."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a {what} file")
    if not path.is_file():
        raise InputError(f"{path}: {what} not found")
    with open(path, "rb") as f:
        head = f.read(4)
    if not head:
        raise InputError(f"{path}: an empty file, not a {what}")
    archive = head.startswith((b"PK\x03\x04", b"PK\x05\x06"))  # torch.save's zip; b"\x80": its legacy pickle
    if not archive and not head.startswith(b"\x80"):
        raise InputError(f"{path}: not a {what}: not a PyTorch archive")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - unpickling errors, truncation, zip errors: all bad input
        if "weights_only" in str(e) or "Unsupported global" in str(e):
            raise InputError(f"{path}: holds pickled Python objects, refused (only plain state dicts load)") from None
        if archive:
            raise InputError(f"{path}: truncated or corrupted {what} ({first_sentence(e)})") from None
        raise InputError(f"{path}: not a readable {what} ({type(e).__name__}: {first_sentence(e)})") from None


def load_checkpoint(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, Any]]:
    """Load ``(payload, record)`` safely (`torch_load`); any problem is one line naming the file."""
    path = Path(path)
    payload = torch_load(path)
    if not isinstance(payload, dict) or "model" not in payload or "record_json" not in payload:
        raise InputError(f"{path}: not an MVRackLay checkpoint (no model state or record)")
    if not isinstance(payload["record_json"], str):
        raise InputError(f"{path}: checkpoint record is not valid JSON")
    record = loads_json(payload["record_json"], f"{path} (record)")
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise InputError(f"{path}: not an MVRackLay checkpoint (format {record.get('format')!r})")
    if record.get("format_version") != FORMAT_VERSION:
        raise InputError(f"{path}: checkpoint format version {record.get('format_version')!r} is not supported")
    check_record(record, str(path))  # the declared schema of the keys the loaders read (`network.checkpoint_schema`)
    return payload, record


def load_model(path: str | os.PathLike) -> tuple[MVRackLay, dict[str, Any]]:
    """Rebuild the model from a checkpoint (float32, eval mode) and return it with its record."""
    payload, record = load_checkpoint(path)
    return model_from(payload, record, path), record


def check_finite(state: dict[str, Any], path: str | os.PathLike) -> None:
    """One line naming the first tensor of a state dict holding NaN or infinite values (a diverged or damaged
    checkpoint: it would map nothing, silently)."""
    for k, v in state.items():
        if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(torch.isfinite(v).all()):
            bad = int((~torch.isfinite(v)).sum())
            raise InputError(
                f"{path}: tensor {k} holds {bad} NaN or infinite values of {v.numel()}; not a usable model"
            )


def model_from(payload: dict[str, Any], record: dict[str, Any], path: str | os.PathLike) -> MVRackLay:
    """The model (float32, eval mode, the record's box and rack-depth offsets) of a loaded checkpoint
    (`load_checkpoint`)."""
    cfg = ModelConfig.from_dict(record.get("model_config"), f"{path} (model_config)")
    model = MVRackLay(cfg)
    state = payload["model"]
    if not isinstance(state, dict):
        raise InputError(f"{path}: model state is not a state dict")
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    extra = sorted(set(state) - set(own))
    if missing or extra:
        raise InputError(f"{path}: model state does not fit its config: missing {missing[:3]}, unexpected {extra[:3]}")
    bad = [k for k in own if tuple(own[k].shape) != tuple(state[k].shape)]
    if bad:
        raise InputError(
            f"{path}: tensor {bad[0]} has shape {tuple(state[bad[0]].shape)}, want {tuple(own[bad[0]].shape)}"
        )
    check_finite(state, path)
    model.load_state_dict({k: v.to(own[k].dtype) for k, v in state.items()})
    model.box_logit_offset = check_offsets(record.get("box_logit_offset"), f"{path} (record)")
    model.rack_depth_offset = check_depth_offset(record.get("rack_depth_offset"), f"{path} (record)")
    return model.eval()


def export_weights(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    half: bool = True,
    note: str | None = None,
    discriminators: bool = False,
) -> dict[str, Any]:
    """Strip a training checkpoint to the model's weights (fp16 by default) for shipping.

    ``note`` (how it was trained, what it reproduces) is kept in the record beside it.
    ``discriminators``: keep them too (same precision), so that a warm start from the copy
    (`init_weights_from`) continues with trained discriminators, as from the full checkpoint.
    """
    payload, record = load_checkpoint(src)

    def cast(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {k: (v.half() if half and v.is_floating_point() else v) for k, v in state.items()}

    out: dict[str, Any] = {"model": cast(payload["model"])}
    if discriminators:
        if not isinstance(payload.get("discriminators"), dict):
            raise InputError(f"{src}: has no discriminators to keep (a variant or run without them)")
        out["discriminators"] = cast(payload["discriminators"])
    record = dict(record)
    record["exported_from"] = Path(src).name
    record["dtype"] = "float16" if half else "float32"
    if note:
        record["note"] = note
    record.pop("format", None)
    record.pop("format_version", None)
    save_checkpoint(dst, out, record)
    return record


#: settings a warm start must share with its source (the rest of the weights' shapes follow from them)
_INIT_SHARED = ("input_width", "input_height", "spec", "encoder_width", "hidden", "decoder_width")


def init_weights_from(
    model: MVRackLay, path: str | os.PathLike, discs: torch.nn.Module | None = None
) -> dict[str, Any]:
    """Warm start: copy a trained checkpoint's weights (any variant) into a fresh ``model``.

    Every variant shares the single-frame network, so a ``racklay`` checkpoint fills all of a
    sequence model but its slot memory, whose zero-initialised output keeps the start equal to
    the source. Discriminators are copied too when both have them. Returns a summary for the
    run's record: the source, its training minutes, and the tensors left at their fresh values.
    """
    payload, record = load_checkpoint(path)
    src_cfg = ModelConfig.from_dict(record.get("model_config"), f"{path} (model_config)")
    for name in _INIT_SHARED:
        if getattr(src_cfg, name) != getattr(model.cfg, name):
            raise InputError(
                f"{path}: cannot warm-start from it: {name} is {getattr(src_cfg, name)!r}, "
                f"the new model has {getattr(model.cfg, name)!r}"
            )
    state = dict(payload["model"])
    own = model.state_dict()
    take = {k: v.to(own[k].dtype) for k, v in state.items() if k in own and tuple(v.shape) == tuple(own[k].shape)}
    model.load_state_dict(take, strict=False)
    fresh = sorted(set(own) - set(take))
    src_discs = payload.get("discriminators")
    copied_discs = False
    if discs is not None and isinstance(src_discs, dict):
        d_own = discs.state_dict()
        if set(src_discs) == set(d_own) and all(tuple(src_discs[k].shape) == tuple(d_own[k].shape) for k in d_own):
            discs.load_state_dict(src_discs)
            copied_discs = True
    return {
        "path": str(path),
        "variant": src_cfg.variant,
        "step": record.get("step"),
        "train_wall_minutes": record.get("train_wall_minutes"),
        "train_cpu_minutes": record.get("train_cpu_minutes"),
        "fresh_tensors": len(fresh),
        "fresh_prefixes": sorted({".".join(k.split(".")[:2]) for k in fresh}),
        "discriminators": copied_discs,
    }
