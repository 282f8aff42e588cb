"""The evaluate jobs (``mvracklay evaluate`` and ``evaluate-baseline``, a recipe's stages of those names):
Table I of a checkpoint, or of the depth-projection baseline, on a dataset, from their settings
(`mvracklay.command_settings`)."""

from __future__ import annotations

from layouts.errors import InputError
from mvracklay.command_settings import EvaluateBaselineSettings, EvaluateSettings


def evaluate(args: EvaluateSettings) -> int:
    """Table I of a checkpoint on a dataset, as ``mvracklay evaluate`` prints it (and ``--json-out`` writes it)."""
    from dataclasses import replace

    from layouts.fileio import atomic_write_json, nan_to_null
    from layouts.metrics import format_reference_table, format_table
    from layouts.publish import refuse_overlap
    from mvracklay.threads import resolve_threads
    from network.inference.layout_eval import evaluate_sequences, table_title
    from network.inference.loading import load_for_inference
    from network.inference.roll import ANGLES, check_angle, describe_angles
    from network.model.frozen import trunk_precision
    from network.training.train_data import open_data

    refuse_overlap(
        [args.json_out] if args.json_out else [], {"--data": args.data, "--checkpoint": args.checkpoint}, "--json-out"
    )
    settings = args.inference
    settings.validate()
    fuse_tau = settings.fuse_tau
    # an angle not given is each sequence's recorded one (0 for a level camera)
    roll, pitch, yaw = (check_angle(a, "--" + n) for a, n in zip((settings.roll, settings.pitch, settings.yaw), ANGLES))
    model, record = load_for_inference(
        args.checkpoint, "evaluate", args.device, args.precision, resolve_threads(args.threads)
    )
    ds = open_data(args.data)
    seqs = ds.sequences(None if args.split == "all" else args.split)
    if not seqs:
        raise InputError(f"{args.data}: has no '{args.split}' sequences")
    res = evaluate_sequences(
        model,
        seqs,
        mode=args.mode,
        max_frames=args.max_frames or None,
        progress=not args.quiet,
        true_anchors=args.true_anchors,
        flip=settings.flip,
        read_depth=settings.read_depth,
        whole_sequence=settings.whole_sequence,
        fuse_tau=fuse_tau,
        roll=roll,
        pitch=pitch,
        yaw=yaw,
        reference=args.metric != "ours",
    )
    title = table_title(
        record.get("variant"), f"{args.data} [{args.split}]", args.mode, model, res, len(seqs),
        replace(settings, roll=roll, pitch=pitch, yaw=yaw), args.true_anchors,
    )  # fmt: skip
    if args.metric != "reference":
        print(format_table(res["visible"], title + " -- columns in view"))
        print()
        print(format_table(res["all"], title + " -- all cells"))
    if args.metric != "ours":
        if args.metric == "both":
            print()
        windows = f"{res['reference_windows']} windows of {len(seqs)} sequences"
        print(format_reference_table(res["reference"], f"{title} -- reference metric, {windows}"))
    print(f"\nframes whose shelf-slot count the row head got right: {100 * res['slot_count_accuracy']:.1f} %")
    lists = {"roll": (roll, res["rolls"]), "pitch": (pitch, res["pitches"]), "yaw": (yaw, res["yaws"])}
    for line in describe_angles({w: v for w, (given, v) in lists.items() if given == "auto"}):
        print(line)
    if args.json_out:
        out = {
            "checkpoint": str(args.checkpoint),
            "data": str(args.data),
            "split": args.split,
            "metric": args.metric,
            "sequences": len(seqs),
            "variant": record.get("variant"),
            "precision": trunk_precision(model),
            **res,
        }
        atomic_write_json(args.json_out, nan_to_null(out))
        print(f"wrote {args.json_out}")
    return 0


def evaluate_baseline(args: EvaluateBaselineSettings) -> int:
    """Table I of the depth-projection baseline on a dataset, printed (and ``--json-out`` written)."""
    from layouts.fileio import atomic_write_json, nan_to_null
    from layouts.metrics import format_table
    from layouts.publish import refuse_overlap
    from mvracklay.baselines.depth_projection import evaluate_depth_projection
    from waresynth.dataset import open_dataset

    refuse_overlap([args.json_out] if args.json_out else [], {"--data": args.data}, "--json-out")
    if args.max_frames < 0:
        raise InputError(f"--max-frames must be >= 0, got {args.max_frames}")
    ds = open_dataset(args.data)
    seqs = ds.sequences(None if args.split == "all" else args.split)
    if not seqs:
        raise InputError(f"{args.data}: has no '{args.split}' sequences")
    res = evaluate_depth_projection(seqs, args.max_frames or None, progress=not args.quiet)
    title = f"depth-projection baseline on {args.data} [{args.split}], {res['frames']} frames of {len(seqs)} sequences"
    print(format_table(res["visible"], title + " -- columns in view"))
    print()
    print(format_table(res["all"], title + " -- all cells"))
    if args.json_out:
        atomic_write_json(
            args.json_out, nan_to_null({"data": str(args.data), "split": args.split, "sequences": len(seqs), **res})
        )
        print(f"wrote {args.json_out}")
    return 0
