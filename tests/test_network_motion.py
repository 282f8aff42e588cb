"""Camera motion read from canonical images, and the slot memory that follows it."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from layouts import VIEWS, InputError
from layouts.canonical import CanonicalView
from layouts.spec import LayoutSpec
from network.inference.predictor import Predictor
from network.model.config import ModelConfig
from network.model.memory import shift_columns
from network.model.motion import MAX_SHIFT, StepReader, camera_motion, camera_shift, motion_signature
from network.model.net import MVRackLay
from network.training.fit_box_depth import with_box_head
from network.training.head_inputs import HeadInputPredictor
from network.training.toy import ToySequence
from tests.test_network_model import ANCHORS, tiny
from tests.tiny_net import tiny_config

VIEW = CanonicalView(128, 96, 3.0)


def _texture(width: int, seed: int) -> torch.Tensor:
    """A smooth random RGB texture ``(3, H, width)`` with features at several scales."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 3, VIEW.height // 4, width // 4, generator=g)
    x = torch.nn.functional.interpolate(x, size=(VIEW.height, width), mode="bilinear", align_corners=False)
    return (x + 0.3 * torch.rand(1, 3, VIEW.height, width, generator=g))[0]


@pytest.mark.parametrize("pixels", [-11.0, -3.0, 0.0, 4.0, 17.0])
def test_camera_shift_recovers_a_known_motion(pixels):
    wide = _texture(VIEW.width + 40, seed=3)
    k = int(pixels)
    prev = wide[:, :, 20 : 20 + VIEW.width]
    cur = wide[:, :, 20 + k : 20 + k + VIEW.width]  # the camera moved k pixels right: content moved left
    sig = motion_signature(torch.stack([prev, cur]))
    dx = camera_shift(sig[:1], sig[1:], VIEW)
    assert dx.shape == (1,)
    assert abs(float(dx[0]) - k * VIEW.metres_per_pixel) < 0.3 * VIEW.metres_per_pixel


def test_camera_shift_is_antisymmetric_and_bounded():
    wide = _texture(VIEW.width + 40, seed=4)
    a, b = wide[:, :, 10 : 10 + VIEW.width], wide[:, :, 17 : 17 + VIEW.width]
    sig = motion_signature(torch.stack([a, b]))
    fwd, back = camera_shift(sig[:1], sig[1:], VIEW), camera_shift(sig[1:], sig[:1], VIEW)
    torch.testing.assert_close(fwd, -back, atol=1e-3, rtol=0)
    noise = motion_signature(torch.rand(6, 3, VIEW.height, VIEW.width, generator=torch.Generator().manual_seed(0)))
    assert camera_shift(noise[:3], noise[3:], VIEW).abs().max() <= MAX_SHIFT + 1e-6


SQUARE = CanonicalView(128, 128, 3.0)  # 16 bands of 8 rows


def _layered(moves: list[int], seed: int, border: int = 0) -> torch.Tensor:
    """Two frames ``(2, 3, 128, 128)``: band i (8 rows) moves ``moves[i]`` pixels left between them.

    ``border`` columns at each side hold the warp's constant fill (outside the source image).
    """
    wide = _texture(SQUARE.width + 60, seed=seed)
    wide = torch.nn.functional.interpolate(wide[None], size=(SQUARE.height, SQUARE.width + 60))[0]
    prev, cur = wide[:, :, 20 : 20 + SQUARE.width].clone(), torch.empty(3, SQUARE.height, SQUARE.width)
    for i, k in enumerate(moves):
        rows = slice(8 * i, 8 * i + 8)
        cur[:, rows] = wide[:, rows, 20 + k : 20 + k + SQUARE.width]
    frames = torch.stack([prev, cur])
    if border:
        fill = torch.tensor([0.49, 0.45, 0.41])[:, None, None]
        frames[..., :border] = fill
        frames[..., -border:] = fill
    return frames


def _read(frames: torch.Tensor) -> float:
    sig = motion_signature(frames)
    return float(camera_shift(sig[:1], sig[1:], SQUARE)[0]) / SQUARE.metres_per_pixel


def test_camera_shift_reads_the_front_plane_not_the_background():
    # 12 bands of background (a wall 1.7 m behind: 0.6 of the motion), 4 bands of rack front
    moves = [4] * 6 + [7] * 4 + [4] * 6
    assert abs(_read(_layered(moves, seed=7)) - 7) < 0.3
    # the front plane at the top, a floor below it whose motion grows toward the camera
    moves = [7] * 8 + [4] * 4 + [8, 9, 11, 13]
    assert abs(_read(_layered(moves, seed=8)) - 7) < 0.3
    # seen the other way round (camera moving left), the same magnitude
    assert abs(_read(_layered(moves, seed=8).flip(0)) + 7) < 0.3


def test_camera_shift_ignores_the_static_edge_of_the_source_image():
    # 32 fill columns each side (a source narrower than the canonical view) around a dim scene:
    # the fill's edge is the strongest and does not move (unmasked, it reads ~0.1 pixel)
    frames = _layered([6] * 16, seed=9, border=32)
    inner = frames[..., 32:-32]
    frames[..., 32:-32] = (inner - inner.mean()) * 0.3 + 0.6
    assert abs(_read(frames) - 6) < 0.3
    with pytest.raises(ValueError, match="signatures"):
        camera_shift(torch.zeros(1, 128, 128), torch.zeros(1, 128, 128), SQUARE)


@pytest.mark.parametrize("bands", [2, 3])  # bands of equal height (summed over a reshape) and not (index_add_)
def test_band_profiles_are_the_normalised_correlation_over_pixels_valid_in_both(bands):
    from network.model.motion import _correlate, _spectra, fft_length

    g = torch.Generator().manual_seed(11)
    frames = torch.rand(2, 3, 16, 40, generator=g)
    sig = motion_signature(frames)
    sig[0, :, :, :5] = 0.0  # the first frame's 5 left columns outside its source image
    n = fft_length(40 + 6 + 1)
    band, whole = _correlate(_spectra(sig[:1], n), _spectra(sig[1:], n), n, 6, bands)
    first = slice(0, -(-16 // bands))  # the first band's rows
    for k in (-6, -1, 0, 3, 6):
        p, c = (sig[0, :, :, k:], sig[1, :, :, : 40 - k]) if k >= 0 else (sig[0, :, :, : 40 + k], sig[1, :, :, -k:])
        for rows, got in ((first, band[0, 0, k + 6]), (slice(0, 16), whole[0, k + 6])):
            keep = (p[1, rows] * c[1, rows]) > 0
            a, b = p[0, rows][keep].double(), c[0, rows][keep].double()
            want = float(((a - a.mean()) * (b - b.mean())).sum() / ((a - a.mean()).norm() * (b - b.mean()).norm()))
            assert abs(float(got) - want) < 1e-4, (k, rows)


def test_fft_lengths_are_the_smallest_with_factors_2_3_5():
    from network.model.motion import fft_length

    def smooth(n: int) -> bool:
        for p in (2, 3, 5):
            while n % p == 0:
                n //= p
        return n == 1

    for n in range(1, 400):
        got = fft_length(n)
        assert got >= n and smooth(got) and not any(smooth(k) for k in range(n, got)), n
    assert fft_length(308) == 320  # the correlation's length at 256x256


def test_shift_columns_moves_content_against_the_camera():
    x = torch.zeros(2 * 3, 1, 2, 8)  # 2 frames x 3 slots, 8 columns over 4 m: 0.5 m per column
    x[..., 5] = 1.0
    out = shift_columns(x, torch.tensor([0.5, -1.0]), 4.0, slots=3)
    assert torch.equal(out[:3, ..., 4], torch.ones(3, 1, 2))  # camera +0.5 m: one column left
    assert torch.equal(out[3:, ..., 7], torch.ones(3, 1, 2))  # camera -1 m: two columns right
    assert float(out.sum()) == 2 * 3 * 2
    entering = shift_columns(torch.ones(1, 1, 1, 8), torch.tensor([1.0]), 4.0, slots=1)
    assert torch.equal(entering[0, 0, 0], torch.tensor([1.0] * 6 + [0.0] * 2))  # newly seen cells start empty


def test_aligned_memory_streams_like_the_window_and_differs_from_unaligned():
    torch.manual_seed(2)
    wide = _texture(64 + 60, seed=5)
    frames = torch.stack(
        [torch.nn.functional.interpolate(wide[None, :, :, 5 * t : 5 * t + 64], size=(64, 64))[0] for t in range(5)]
    )[None].clamp(0, 1)
    aligned = MVRackLay(tiny()).eval()
    torch.nn.init.normal_(aligned.memory.out.weight, std=0.5)
    plain = MVRackLay(replace(tiny(), align_memory=False)).eval()
    plain.load_state_dict(aligned.state_dict())
    with torch.no_grad():
        a = aligned(frames, ANCHORS.expand(1, 5, 2))
        p = plain(frames, ANCHORS.expand(1, 5, 2))
        state = None
        for t in range(5):
            out, state = aligned.step(frames[:, t], state, ANCHORS[None])
            torch.testing.assert_close(out["top"], a["top"][:, t], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(a["top"][:, 0], p["top"][:, 0])  # first frame: nothing to align yet
    assert not torch.allclose(a["top"][:, 4], p["top"][:, 4], atol=1e-4)


def test_records_written_before_alignment_load_unaligned():
    d = tiny().to_dict()
    del d["align_memory"]
    assert ModelConfig.from_dict(d).align_memory is False
    assert tiny().align_memory is True
    with pytest.raises(InputError, match="align_memory"):
        replace(tiny(), align_memory="yes")


def test_a_given_camera_step_replaces_the_image_estimate():
    torch.manual_seed(3)
    wide = _texture(64 + 60, seed=6)
    frames = torch.stack(
        [torch.nn.functional.interpolate(wide[None, :, :, 5 * t : 5 * t + 64], size=(64, 64))[0] for t in range(3)]
    ).clamp(0, 1)
    model = MVRackLay(tiny()).eval()
    torch.nn.init.normal_(model.memory.out.weight, std=0.5)
    view = model.memory.view
    with torch.no_grad():
        sig = motion_signature(frames)
        estimate = camera_shift(sig[:-1], sig[1:], view)

        def stream(motions):
            state = None
            for t in range(3):
                out, state = model.step(frames[t : t + 1], state, ANCHORS[None], motion=motions[t])
            return out["top"]

        by_image = stream([None, None, None])
        given_estimate = stream([None, estimate[:1], estimate[1:]])
        given_zero = stream([None, torch.zeros(1), torch.zeros(1)])
        torch.testing.assert_close(given_estimate, by_image, rtol=1e-4, atol=1e-5)
        assert not torch.allclose(given_zero, by_image, atol=1e-4)
        with pytest.raises(InputError, match="motion"):
            model.step(frames[:1], None, ANCHORS[None], motion=torch.tensor([float("nan")]))
        with pytest.raises(InputError, match="motion"):
            model.step(frames[:1], None, ANCHORS[None], motion=torch.zeros(2))


def test_the_predictor_reads_each_step_once_and_streams_as_the_memory_reading_its_own(monkeypatch):
    """`Predictor` reads the camera's step once per frame and gives it to the memory: the same outputs
    as `MVRackLay.step` reading the steps itself, one estimate per frame after the first, none in the
    model; the mirrored pass of ``flip`` still reads its own. `HeadInputPredictor`'s ``box_inputs_from`` is checked by name."""
    spec = LayoutSpec(size=16)
    torch.manual_seed(4)
    model = with_box_head(MVRackLay(tiny_config(spec)).eval(), parallax=True)
    torch.nn.init.normal_(model.memory.out.weight, std=0.5)
    assert model.memory.view is not None
    seq = ToySequence(spec, num_frames=5, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(5)]
    pred = Predictor(model, read_depth=False)
    with torch.no_grad():
        want, state = [], None
        for i, f in enumerate(frames):
            out, state = model.step(pred.preprocess(f, i), state)
            want.append(out)
    calls = {"infer": 0, "model": 0}

    def counted(where):
        def shift(prev, cur, view):
            calls[where] += 1
            return camera_shift(prev, cur, view)

        return shift

    class Counted(StepReader):  # the predictor's reader: a step read for every frame after the first
        def __call__(self, sig):
            calls["infer"] += self._prev is not None
            return super().__call__(sig)

    monkeypatch.setattr("network.inference.predictor.StepReader", Counted)
    monkeypatch.setattr("network.model.memory.camera_shift", counted("model"))
    got = list(HeadInputPredictor(model, read_depth=False).stream(frames))
    assert calls == {"infer": 4, "model": 0}
    for g, w in zip(got, want):
        for v in VIEWS:
            assert torch.equal(getattr(g, v), w[v][0])
    calls.update(infer=0, model=0)
    list(Predictor(model, read_depth=False, flip=True).stream(frames))
    assert calls == {"infer": 4, "model": 4}
    calls.update(infer=0, model=0)
    list(Predictor(model, read_depth=False).window(frames))  # each window's memory reads its own; no reader needs one
    assert calls["infer"] == 0 and calls["model"] > 0
    for bad in (-1, 1.5, True):
        with pytest.raises(InputError, match="box_inputs_from"):
            HeadInputPredictor(model, read_depth=False, box_inputs_from=bad)
    with pytest.raises(InputError, match="box_inputs_from"):
        HeadInputPredictor(model, rack_depth=0.8, box_inputs_from=2)  # the head reads: it needs every frame's maps


def test_the_step_reader_reads_what_camera_motion_reads_frame_after_frame():
    """`StepReader` (each frame's spectra made once) gives `camera_motion` of each consecutive pair, bit for bit,
    and 0 (confidence 1) for the first frame."""
    tex = _texture(200, 3)
    sigs = [motion_signature(tex[None, :, :, 8 * t : 8 * t + 128]) for t in range(4)]
    reader = StepReader(VIEW)
    first = reader(sigs[0])
    assert first[0].tolist() == [0.0] and first[1].tolist() == [1.0]
    for prev, cur in zip(sigs, sigs[1:]):
        step, conf = reader(cur)
        want_step, want_conf = camera_motion(prev, cur, VIEW)
        assert torch.equal(step, want_step) and torch.equal(conf, want_conf)
        assert abs(float(step[0]) - 8 * VIEW.metres_per_pixel) < 0.3 * VIEW.metres_per_pixel
    with pytest.raises(ValueError, match="signature"):
        reader(sigs[0][:, :1])
