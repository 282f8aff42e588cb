"""Generator configuration: the embedded defaults, user overrides and validation.

A config is a nested JSON object (see ``default_config.json`` and docs/waresynth.md). A user
config overrides any subset of keys; keys starting with ``_`` are comments. Unknown keys and
bad values are refused with one line naming the key, e.g.
``config.json: camera.distance must be [low, high] with low <= high, got [3, 2]``. The merged config
is then checked against the declared schema made from the defaults and `_BOUNDS`
(`waresynth.config_schema`).
"""

from __future__ import annotations

import copy
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from layouts.canonical import MAX_ROLL_DEG
from layouts.errors import InputError
from layouts.fileio import load_json
from waresynth.look import COMPRESSIONS, SUBSAMPLING

DEFAULT_CONFIG_PATH = Path(__file__).with_name("default_config.json")
#: the shipped configs (`load_config` takes their names: "wide_look", "wide_camera", "shifted_look", joined by "+")
CONFIGS_DIR = Path(__file__).with_name("configs")

#: Texture names each section may use (renderer patterns).
TEXTURES: dict[str, tuple[str, ...]] = {
    "rack": ("plain", "perforated", "noise", "stained"),
    "boxes": ("plain", "tape", "label", "noise", "wrap", "printed", "stained"),
    "floor": ("plain", "tiles", "noise", "stained", "lines"),
    "wall": ("plain", "bricks", "panels", "noise", "stained"),
}
#: Other keys that take a non-empty list of names, one drawn per sequence, and the names each allows.
_NAME_LISTS: dict[str, tuple[str, ...]] = {
    "rack.board_textures": ("wood", "plain", "noise", "stained"),
    "sensor.compression": COMPRESSIONS,
    "sensor.jpeg_subsampling": tuple(SUBSAMPLING),
}

_INF = math.inf
#: Allowed value range per key ("*" matches any density preset name) and whether it is an integer.
_BOUNDS: dict[str, tuple[float, float, bool]] = {
    "camera.hfov_deg": (10.0, 150.0, False),
    "camera.distance": (0.3, 50.0, False),
    "camera.height": (0.2, 50.0, False),
    "camera.step": (0.0, 10.0, False),
    "camera.reverse_probability": (0.0, 1.0, False),
    "camera.roll_deg": (-MAX_ROLL_DEG, MAX_ROLL_DEG, False),
    "camera.pitch_deg": (-MAX_ROLL_DEG, MAX_ROLL_DEG, False),
    "camera.yaw_deg": (-MAX_ROLL_DEG, MAX_ROLL_DEG, False),
    "rack.levels": (1, 12, True),
    "rack.first_level": (0.0, 10.0, False),
    "rack.spacing": (0.2, 10.0, False),
    "rack.top_clearance": (0.1, 10.0, False),
    "rack.depth": (0.2, 10.0, False),
    "rack.width": (0.5, 50.0, False),
    "rack.gap": (0.2, 50.0, False),
    "rack.wide_gap_probability": (0.0, 1.0, False),
    "rack.wide_gap": (0.2, 50.0, False),
    "rack.board_thickness": (0.005, 0.5, False),
    "rack.upright_width": (0.01, 0.5, False),
    "rack.colour_jitter": (0.0, 1.0, False),
    "boxes.density.*.weight": (0.0, _INF, False),
    "boxes.density.*.gap": (0.0, 50.0, False),
    "boxes.density.*.empty_probability": (0.0, 1.0, False),
    "boxes.density.*.stack_probability": (0.0, 1.0, False),
    "boxes.width": (0.05, 10.0, False),
    "boxes.depth": (0.05, 10.0, False),
    "boxes.height": (0.05, 10.0, False),
    "boxes.max_stack": (1, 20, True),
    "boxes.head_room": (0.0, 5.0, False),
    "boxes.setback": (0.0, 5.0, False),
    "boxes.yaw_deg": (0.0, 90.0, False),
    "boxes.yaw_probability": (0.0, 1.0, False),
    "boxes.reflectance": (0.0, 1.0, False),
    "boxes.colour_jitter": (0.0, 1.0, False),
    "background.busy_probability": (0.0, 1.0, False),
    "background.wall_distance": (0.2, 100.0, False),
    "background.busy_wall_distance": (0.5, 100.0, False),
    "background.background_rack_distance": (0.3, 100.0, False),
    "background.props_per_gap": (0, 50, True),
    "background.end_props": (0, 50, True),
    "floor.colour_jitter": (0.0, 1.0, False),
    "wall.colour_jitter": (0.0, 1.0, False),
    "lighting.ambient": (0.0, 1.0, False),
    "lighting.intensity": (0.0, 5.0, False),
    "lighting.light_height": (0.5, 100.0, False),
    "lighting.light_offset_z": (-50.0, 50.0, False),
    "lighting.shadow_strength": (0.0, 1.0, False),
    "lighting.level": (0.01, 4.0, False),
    "lighting.falloff": (0.0, 1.0, False),
    "lighting.extra_lights": (0, 8, True),
    "lighting.extra_intensity": (0.0, 5.0, False),
    "lighting.colour_temperature": (1500.0, 15000.0, False),
    "sensor.noise_sigma": (0.0, 100.0, False),
    "sensor.gain": (0.1, 10.0, False),
    "sensor.supersample": (1, 4, True),
    "sensor.motion_blur": (0.0, 1.0, False),
    "sensor.motion_blur_probability": (0.0, 1.0, False),
    "sensor.exposure_ev": (-4.0, 4.0, False),
    "sensor.auto_exposure": (0.0, 1.0, False),
    "sensor.white_balance_jitter": (0.0, 0.5, False),
    "sensor.shot_noise": (0.0, 20.0, False),
    "sensor.read_noise": (0.0, 50.0, False),
    "sensor.gamma": (0.5, 3.0, False),
    "sensor.vignetting": (0.0, 0.9, False),
    "sensor.lens_k1": (-0.5, 0.5, False),
    "sensor.lens_k2": (-0.3, 0.3, False),
    "sensor.jpeg_quality": (1, 100, True),
    "sensor.h264_quality": (1, 100, True),
    "sensor.h264_blur": (0.0, 3.0, False),
    "sensor.stream_mbps": (0.05, 100.0, False),
}
#: keys that take one number or a [low, high] range drawn per sequence (the default's type is the number)
_NUMBER_OR_RANGE = frozenset({"camera.hfov_deg"})


def default_config() -> dict[str, Any]:
    """The embedded default config (a fresh copy, comment keys removed)."""
    text = DEFAULT_CONFIG_PATH.read_text(encoding="utf-8")
    return _strip_comments(json.loads(text))


def _strip_comments(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _strip_comments(v) for k, v in d.items() if not (isinstance(k, str) and k.startswith("_"))}
    return d


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _bounds_for(key: str) -> tuple[float, float, bool] | None:
    if key in _BOUNDS:
        return _BOUNDS[key]
    parts = key.split(".")
    if len(parts) == 4 and parts[:2] == ["boxes", "density"]:
        return _BOUNDS.get(f"boxes.density.*.{parts[3]}")
    return None


def _check_leaf(src: str, key: str, value: Any, default: Any) -> None:
    """Check one user value against the type of the default and the key's bounds."""
    section = key.split(".")[0]
    if key in _NAME_LISTS or key.endswith(".textures"):
        allowed = _NAME_LISTS.get(key) or TEXTURES[section]
        what = "textures" if key.endswith("textures") else "names"
        if not isinstance(value, list) or not value or not all(isinstance(t, str) and t in allowed for t in value):
            raise InputError(f"{src}: {key} must be a non-empty list of {what} from {list(allowed)}, got {value!r}")
        return
    if key.endswith("colours"):
        ok = (
            isinstance(value, list)
            and value
            and all(isinstance(c, list) and len(c) == 3 and all(_is_num(x) and 0 <= x <= 255 for x in c) for c in value)
        )
        if not ok:
            raise InputError(f"{src}: {key} must be a non-empty list of [r, g, b] with values in 0..255, got {value!r}")
        return
    bounds = _bounds_for(key)
    lo, hi, integer = bounds if bounds else (-_INF, _INF, False)
    kind = "an integer" if integer else "a number"
    if key in _NUMBER_OR_RANGE and isinstance(value, list):
        default = [default, default]
    if isinstance(default, list):
        if not (isinstance(value, list) and len(value) == 2 and all(_is_num(x) for x in value)):
            raise InputError(f"{src}: {key} must be [low, high] ({kind} each), got {value!r}")
        if value[0] > value[1]:
            raise InputError(f"{src}: {key} must be [low, high] with low <= high, got {value!r}")
        items = value
    else:
        if not _is_num(value):
            either = " or [low, high]" if key in _NUMBER_OR_RANGE else ""
            raise InputError(f"{src}: {key} must be {kind}{either}, got {value!r}")
        items = [value]
    for x in items:
        if integer and float(x) != int(x):
            raise InputError(f"{src}: {key} must be {kind}, got {value!r}")
        if not lo <= x <= hi:
            raise InputError(f"{src}: {key} must lie in [{lo:g}, {hi:g}], got {value!r}")


def draw_hfov(cfg: dict[str, Any], seed: int) -> float:
    """A sequence's horizontal field of view (degrees): ``camera.hfov_deg`` itself, or drawn uniformly from
    its ``[low, high]`` range by the sequence seed's own stream (so the scene, the noise and every other
    draw are those of a fixed camera with the same seed)."""
    fov = cfg["camera"]["hfov_deg"]
    if not isinstance(fov, list):
        return float(fov)
    return float(np.random.default_rng(np.random.SeedSequence([seed, 2])).uniform(float(fov[0]), float(fov[1])))


def _merge(src: str, base: dict[str, Any], user: dict[str, Any], prefix: str = "") -> None:
    for k, v in user.items():
        if isinstance(k, str) and k.startswith("_"):
            continue
        key = f"{prefix}{k}"
        if k not in base:
            raise InputError(f"{src}: unknown key {key!r}")
        if isinstance(base[k], dict):
            if not isinstance(v, dict):
                raise InputError(f"{src}: {key} must be an object, got {v!r}")
            _merge(src, base[k], v, key + ".")
        else:
            _check_leaf(src, key, v, base[k])
            base[k] = copy.deepcopy(v)


def _check_whole(src: str, cfg: dict[str, Any]) -> None:
    """Checks across keys, after merging."""
    weights = [p["weight"] for p in cfg["boxes"]["density"].values()]
    if sum(weights) <= 0:
        raise InputError(f"{src}: boxes.density weights must not all be 0")
    b = cfg["boxes"]
    if b["height"][0] + b["head_room"] >= cfg["rack"]["spacing"][0] - cfg["rack"]["board_thickness"][1]:
        raise InputError(
            f"{src}: boxes.height[0] + boxes.head_room must be below the smallest clear height "
            f"(rack.spacing[0] - rack.board_thickness[1])"
        )
    if b["width"][1] > cfg["rack"]["width"][0] - 2 * cfg["rack"]["upright_width"][1] - 0.05:
        raise InputError(f"{src}: boxes.width[1] must fit between the uprights of the narrowest rack (rack.width[0])")
    if b["depth"][0] + b["setback"][0] > cfg["rack"]["depth"][0]:
        raise InputError(f"{src}: boxes.depth[0] + boxes.setback[0] must not exceed rack.depth[0]")


def shipped_configs() -> list[str]:
    """The names of the shipped configs (``waresynth/configs/NAME.json``)."""
    return sorted(p.stem for p in CONFIGS_DIR.glob("*.json"))


def _shipped(config: str | os.PathLike) -> str | os.PathLike:
    """``config`` itself when it is a file, else the shipped config of that bare name (``wide_look``)."""
    name = str(config)
    if Path(config).is_file() or os.sep in name or "/" in name:
        return config
    shipped = CONFIGS_DIR / f"{name.removesuffix('.json')}.json"
    return shipped if shipped.is_file() else config


def config_parts(config: str | os.PathLike) -> list[str | os.PathLike]:
    """The configs a name stands for, applied in order: a file, a shipped config's name, or shipped names and
    files joined by ``+`` (``"wide_look+wide_camera"``: the wide look with the wide camera geometry)."""
    name = str(config)
    if Path(config).is_file() or "+" not in name:
        return [_shipped(config)]
    return [_shipped(part) for part in name.split("+")]


def is_config(config: str | os.PathLike) -> bool:
    """Whether ``config`` names configs `load_config` finds (every ``+`` part a file or a shipped name)."""
    parts = config_parts(config)
    return all(Path(p).is_file() for p in parts)


def load_config(config: dict[str, Any] | str | os.PathLike | None = None) -> dict[str, Any]:
    """Effective config: the defaults overridden by ``config`` (a dict, a JSON file path, a shipped config's
    name such as ``"wide_look"``, several joined by ``+`` and applied in order, or None)."""
    cfg = default_config()
    if config is None:
        return cfg
    if isinstance(config, (str, os.PathLike)):
        src = str(config)
        users = []
        parts = config_parts(config)
        for part, given in zip(parts, src.split("+") if len(parts) > 1 else [src]):
            if not Path(part).is_file():
                names = ", ".join(shipped_configs())
                raise InputError(f"{given}: config file not found (nor a shipped config: {names})")
            users.append((given, load_json(part)))
    elif isinstance(config, dict):
        src, users = "config", [("config", config)]
    else:
        raise InputError(f"config must be a dict, a JSON file path or None, got {type(config).__name__}")
    for part_src, user in users:
        if not isinstance(user, dict):
            raise InputError(f"{part_src}: config must be a JSON object, got {type(user).__name__}")
        _merge(part_src, cfg, copy.deepcopy(user))
    _check_whole(src, cfg)
    from waresynth.config_schema import check_config

    check_config(cfg, src)  # the declared schema of the whole config (`waresynth.config_schema`)
    return cfg
