"""A run's record's train config read back (`TrainConfig.from_dict`): options of earlier versions load when off,
are refused in one line when on, also on resume."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from layouts.errors import InputError
from network.training.train_config import RETIRED_OPTIONS, TrainConfig, retired_options_off

ROOT = Path(__file__).resolve().parents[1]


def test_a_record_round_trips():
    cfg = TrainConfig(epochs=3, class_weights=(1.0, 2.0, 3.0), jpeg_quality=(40, 90))
    assert TrainConfig.from_dict(json.loads(json.dumps(asdict(cfg)))) == cfg


@pytest.mark.parametrize("name", sorted(RETIRED_OPTIONS))
def test_retired_options_load_off_and_are_refused_on(name):
    record = {**asdict(TrainConfig()), name: 0}
    assert TrainConfig.from_dict(record) == TrainConfig()
    with pytest.raises(InputError, match=f"run/last.pt: trained with {RETIRED_OPTIONS[name]} 2, an option") as e:
        retired_options_off({name: 2}, "run/last.pt")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="unknown train config keys"):
        TrainConfig.from_dict({"no_such_option": 1})


def test_the_shipped_records_train_configs_load():
    paths = sorted((ROOT / "mvracklay" / "models").glob("*.json")) + sorted((ROOT / "weights").glob("*.json"))
    records = [json.loads(p.read_text()) for p in paths]
    configs = [r["train_config"] for r in records if isinstance(r, dict) and "train_config" in r]
    assert configs, "no shipped record with a train config"
    for c in configs:
        assert {k: c[k] for k in RETIRED_OPTIONS if k in c} == dict.fromkeys(RETIRED_OPTIONS.keys() & c.keys(), 0)
        retired_options_off(c, "shipped record")
