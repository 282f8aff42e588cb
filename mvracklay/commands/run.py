"""``mvracklay run``: the main job, from a video or image folder to a 3D warehouse map and free space."""

from __future__ import annotations

import argparse

from layouts.errors import InputError
from mvracklay.options import add_help_all_option, read_config
from mvracklay.presets import preset_defaults
from mvracklay.settings import (
    SERVE_PORT,
    ComputeSettings,
    InferenceSettings,
    LiveSettings,
    OutputSettings,
    RunConfig,
    add_options,
    from_args,
)
from mvracklay.threads import resolve_threads
from mvracklay.use_settings import RunCommandSettings

NAME = "run"
HELP = "the main job: video / image folder / sequence / camera or stream -> 3D map (.glb, .json, .rrd) + free space"
DESCRIPTION = (
    "Run the MVRackLay network over INPUT frame by frame (streaming: one encoder pass per frame, the ConvLSTM "
    "state carried), stitch the per-frame layouts into one 3D map of the rack row, and write OUT/layouts/ "
    "(a layout folder for 'mvracklay reconstruct'), OUT/warehouse.json, OUT/warehouse.glb and "
    "OUT/warehouse.rrd; then print the free space per shelf. INPUT is a WareSynth sequence folder, any folder "
    "of ordered PNG/JPEG images (natural name order, all the same size), a video file, or a live source: a camera "
    "(/dev/video0, or its index 0) or a stream URL (rtsp://, rtmp://, http(s)://, udp://, tcp://, srt://), mapped as "
    "its frames arrive (frames the network cannot keep up with are dropped and counted; the latency and the share "
    "dropped are printed); a live run ends when the stream ends or stays quiet --idle-timeout seconds, or on Ctrl-C "
    "or SIGTERM, and saves the map of what it saw; --spawn streams into a viewer as it maps, --serve serves the "
    "recording to a viewer on another machine. The camera should "
    "move sideways along one rack row at a roughly constant distance, facing the racks, without turning as it "
    "goes; a camera mounted askew is levelled: its roll read from the frames (--roll), a pitch or yaw given or "
    "read (--pitch, --yaw). "
    "Intrinsics: --camera JSON, else the sequence's meta.json, else the default camera (60 deg horizontal "
    "field of view, principal point at the centre) at the frame size. No ground truth is needed. A failed run "
    "leaves OUT as it was."
)
GROUP = "use"
ORDER = 10
#: what the CLI says when a run is interrupted (Ctrl-C, SIGTERM): nothing to resume
INTERRUPTED = "OUT left as it was; run it again to start over"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, RunCommandSettings, only=("input", "out", "overwrite"))
    add_options(p, RunConfig, only=("checkpoint", "camera", "distance", "camera_height"))  # mvracklay.settings
    add_options(p, RunCommandSettings, only=("quality", "config"))
    add_options(p, ComputeSettings, only=("device",))
    add_options(p, ComputeSettings, only=("threads",))
    add_options(p, RunCommandSettings, only=("spawn",))
    add_options(p, LiveSettings, only=("idle_timeout", "serve"))
    add_options(p, OutputSettings, only=("quiet",))
    add_help_all_option(p)
    # the rest: config-file keys, still parseable (--help-all shows them)
    add_options(p, RunConfig, hidden=True, only=("mode", "max_frames", "every", "distance_reader"))
    add_options(p, InferenceSettings, hidden=True)
    add_options(p, RunConfig, hidden=True, only=("layout_size",))
    add_options(p, ComputeSettings, hidden=True, only=("precision",))
    add_options(p, RunConfig, hidden=True, only=("rrd", "rgb", "map_every", "opening", "board_thickness"))
    add_options(p, LiveSettings, hidden=True, only=("retries", "live_buffer"))
    hidden = [a.option_strings[0][2:] for a in p._actions if a.help == argparse.SUPPRESS and hasattr(a, "full_help")]
    p.epilog = (
        f"More options, by their long names in a --config file (or as --NAME here): {', '.join(hidden)}. "
        "--help-all explains them; docs/cli.md the presets and config files."
    )


def config_defaults(args: argparse.Namespace, parser: argparse.ArgumentParser) -> dict[str, object]:
    """The defaults ``--quality`` and ``--config`` give (the command line is parsed again over them)."""
    classes = (RunConfig, InferenceSettings, LiveSettings)
    from_file = read_config(args.config, parser, settings=classes) if args.config else {}
    quality = args.quality or from_file.pop("quality", None) or "default"
    from_file.pop("quality", None)
    return {**preset_defaults(quality), **from_file, "quality": quality}


def run(args: argparse.Namespace) -> int:
    from mvracklay.frames import open_source
    from mvracklay.live import check_viewer
    from mvracklay.live_source import is_live
    from mvracklay.outputs import OUTPUTS, check_apart, check_out, run_summary, spawn_viewer
    from mvracklay.pipeline import resolve_checkpoint, run_pipeline

    if args.out is None:
        raise InputError("--out is required (on the command line or as 'out' in the --config file)")
    live = is_live(args.input)
    check_viewer(args.spawn, args.serve is not None, not args.no_rrd, live)
    cfg = from_args(
        RunConfig,
        args,
        inference=from_args(InferenceSettings, args),
        threads=resolve_threads(args.threads),
        precision=args.precision,
        device=args.device,
        progress=not args.quiet,
    )
    cfg.validate()
    check_out(args.out, args.overwrite)
    check_apart(
        args.out,
        OUTPUTS,
        {"INPUT": args.input, "--camera": args.camera, "--config": args.config, "--checkpoint": args.checkpoint},
    )
    resolve_checkpoint(cfg.checkpoint)  # fail before decoding anything
    if live:
        return _run_live(args, cfg)
    source = open_source(args.input, prog="mvracklay run")
    res = run_pipeline(source, args.out, cfg)
    print(run_summary(res, source))
    if args.spawn:
        spawn_viewer(res.out / "warehouse.rrd")
    return 0


def _run_live(args: argparse.Namespace, cfg: RunConfig) -> int:
    """A live source, mapped until it ends (`mvracklay.live.map_live_source`)."""
    from mvracklay.live import map_live_source
    from mvracklay.outputs import run_summary

    settings = from_args(LiveSettings, args, serve=SERVE_PORT if args.serve is True else args.serve)
    result, source = map_live_source(args.input, args.out, cfg, settings, args.spawn)
    print(run_summary(result.run, source))
    for line in result.report.lines():
        print(line)
    return 0
