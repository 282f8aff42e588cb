"""Stage ``blend``: a fine-tuned network blended back into its base, the base's depth heads and record kept."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model, save_checkpoint
from network.model.config import ModelConfig
from network.model.net import MVRackLay


def _plain(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in ("format", "format_version")}


@pytest.fixture()
def base_and_tuned(tiny_checkpoint, tmp_path):
    """The tiny network with a back-edge head and its offsets (the base), and a copy of its network with every
    weight moved by 0.1 and no head (as `train --init-from` writes it)."""
    payload, record = load_checkpoint(tiny_checkpoint)
    cfg = replace(ModelConfig.from_dict(record["model_config"], "tiny"), back_edges=True)
    head = {k: v for k, v in MVRackLay(cfg).state_dict().items() if k.startswith("back.")}
    base = tmp_path / "base.pt"
    rec = {**_plain(record), "model_config": cfg.to_dict(), "rack_depth_offset": 0.02,
           "box_logit_offset": {"top": 1.25, "front": 1.5}}  # fmt: skip
    save_checkpoint(base, {"model": {**payload["model"], **head}}, rec)
    moved = {k: (v.float() + 0.1 if v.is_floating_point() else v) for k, v in payload["model"].items()}
    tuned = tmp_path / "tuned.pt"
    save_checkpoint(tuned, {"model": moved}, {**_plain(record), "step": 250})
    return base, tuned


def _blend(base, tuned, out, alpha) -> int:
    return run_stage("blend", ["--base", str(base), "--tuned", str(tuned), "--alpha", str(alpha), "--out", str(out)])


def test_the_blend_lies_between_the_networks_and_keeps_the_bases_heads_and_offsets(base_and_tuned, tmp_path):
    base, tuned = base_and_tuned
    b, b_rec = load_checkpoint(base)
    t, _ = load_checkpoint(tuned)
    for alpha in (0.0, 0.3, 1.0):
        out = tmp_path / f"blend{alpha}.pt"
        assert _blend(base, tuned, out, alpha) == 0
        got, rec = load_checkpoint(out)
        for k, v in b["model"].items():
            if k.startswith("back."):
                assert torch.equal(got["model"][k], v), k  # the heads as they were
            elif v.is_floating_point():
                want = (1 - alpha) * v.float() + alpha * t["model"][k].float()
                assert torch.allclose(got["model"][k], want, atol=1e-6), k
        assert rec["rack_depth_offset"] == 0.02 and rec["box_logit_offset"] == b_rec["box_logit_offset"]
        assert rec["model_config"]["back_edges"] is True
        assert rec["blended"]["alpha"] == alpha and rec["blended"]["tuned_step"] == 250
    assert load_model(tmp_path / "blend0.3.pt")[0].back is not None


def test_a_blend_of_other_networks_or_shares_is_refused_in_one_line(base_and_tuned, tmp_path, capsys):
    base, tuned = base_and_tuned
    assert _blend(base, tuned, tmp_path / "a.pt", 1.5) == 2
    assert "--alpha: 1.5 is outside 0..1" in capsys.readouterr().err
    payload, record = load_checkpoint(tuned)
    other = tmp_path / "other.pt"
    cfg = {**record["model_config"], "decoder_width": 16}
    save_checkpoint(other, {"model": payload["model"]}, {**_plain(record), "model_config": cfg})
    assert _blend(base, other, tmp_path / "b.pt", 0.3) == 2
    err = capsys.readouterr().err
    assert "decoder_width is 16, the base's 8" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a.pt").exists() and not (tmp_path / "b.pt").exists()
