"""``mvracklay predict``: per-frame layouts of a sequence, written as a layout folder."""

from __future__ import annotations

from mvracklay.models import DEFAULT_MODEL
from mvracklay.use_settings import PredictSettings

NAME = "predict"
HELP = "predict top/front layouts for every frame of a sequence, image folder, image or video"
DESCRIPTION = (
    "Run a checkpoint over INPUT (the inputs of 'mvracklay run': a generated sequence folder with rgb/ and "
    "meta.json, any folder of images in name order, one image, or a video file) and write a layout folder (spec.json + NNNNNN.npz with top, front, visible) that "
    "'mvracklay reconstruct' reads. Streaming mode carries the ConvLSTM state frame to frame (one encoder "
    "pass per frame); window mode predicts each frame from the last seq_len frames, as in the paper. "
    "Every frame is warped into the model's canonical view with the camera intrinsics and the "
    "camera-to-rack distance, which also give the visible columns: --camera / --distance when given, else "
    "meta.json's, else the default camera and the distance read from the first frames (as 'mvracklay run' "
    "reads it, printed). A wrong distance scales the layouts (and the map) by true / used distance: pass "
    "--distance when you know it. Without --checkpoint it runs the shipped "
    f"{DEFAULT_MODEL}, as 'mvracklay run' does."
)
GROUP = "use"
ORDER = 13
SETTINGS = PredictSettings


def run(args: PredictSettings) -> int:
    from mvracklay.inference import predict_folder
    from mvracklay.models import resolve_checkpoint
    from mvracklay.threads import resolve_threads
    from network.inference.loading import load_for_inference

    args.validate()  # checked before the model loads
    # the shipped default model without --checkpoint (as `run`); a given path keeps the loader's own messages
    ckpt = args.checkpoint if args.checkpoint is not None else resolve_checkpoint(None)
    model, record = load_for_inference(ckpt, NAME, args.device, args.precision, resolve_threads(args.threads))
    n = predict_folder(model, record, args, source=str(ckpt))
    print(f"wrote {n} frames of layouts to {args.out}")
    return 0
