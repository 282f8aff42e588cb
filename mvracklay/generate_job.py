"""The generate job (``mvracklay generate``, a recipe's ``generate`` stage): a WareSynth dataset or a
building's passes, written as its settings (`mvracklay.command_settings.GenerateSettings`) ask, sharded or on
Ray."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from mvracklay.command_settings import GenerateSettings

if TYPE_CHECKING:
    from layouts.spec import LayoutSpec
    from layouts.tasks import TaskMap

DEFAULT_SIZE = 256  #: image width and height without --size (a rescan: SCAN's)


def generate(args: GenerateSettings) -> int:
    """Write the dataset (or ``--building``'s passes) ``args`` asks for, and say what was written."""
    from layouts.spec import LayoutSpec
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    args.validate()
    from layouts.publish import refuse_overlap

    if args.config is not None and Path(args.config).exists():
        refuse_overlap([args.out], {"--config": args.config}, "OUT")
    if args.format != "native" and args.export_out is not None:
        refuse_overlap([args.export_out], {"OUT": args.out}, "--export-out")
    shard = None
    if args.shard is not None:
        from waresynth.generate import parse_shard

        shard = parse_shard(args.shard)
    config = args.config
    if args.supersample is not None:
        from waresynth.config import load_config

        if config is None and args.rescan is not None:  # SCAN's config with the new supersampling
            from waresynth.dataset import read_manifest

            config = read_manifest(args.rescan)[1].get("config")
        config = load_config(config)  # the file checked under its own name first
        config["sensor"]["supersample"] = args.supersample
    given = {k: v for k, v in (("num_slots", args.slots), ("size", args.layout_size)) if v is not None}
    spec = LayoutSpec(**given)
    tasks = None
    if args.ray is not None:  # one Ray task per sequence or pass (mvracklay.parallel)
        from mvracklay.parallel import connect, task_map

        connect(args.ray, args.workers)  # a cluster not found: one line before anything is written
        tasks = task_map(workers=args.workers, ray=args.ray)
    if args.building is not None:
        return _building(args, spec, given, config, tasks)
    size = args.size or DEFAULT_SIZE
    root = generate_dataset(
        args.out,
        DatasetSettings(
            num_sequences=args.sequences,
            frames=args.frames,
            image_size=(size, size),
            spec=spec,
            shard=shard,
            **_written(args, config),
        ),
        tasks=tasks,
    )
    ds = open_dataset(root)
    counts = {s: len(ds.sequences(s)) for s in ("train", "val", "test")}
    what = "" if shard is None else f" (shard {shard[0]}/{shard[1]}; join with `mvracklay merge-shards`)"
    print(
        f"{root}{what}: {sum(counts.values())} sequences x {args.frames} frames "
        f"(train {counts['train']}, val {counts['val']}, test {counts['test']}), "
        f"images {size}x{size}, layouts {spec.shape}"
    )
    if args.format != "native":
        from waresynth.exporters import export_dataset

        dest = args.export_out or root.parent / f"{root.name}_{args.format}"
        if dest.is_dir() and any(dest.iterdir()) and not args.overwrite:
            # A re-run (resume) of the same command: the export was made from this same dataset.
            print(f"{dest}: exists, kept (pass --overwrite to export again)")
            return 0
        out = export_dataset(root, dest, args.format, overwrite=args.overwrite, progress=not args.quiet)
        print(f"{out}: {args.format} export")
    return 0


def _written(args: GenerateSettings, config: object) -> dict[str, object]:
    """What a dataset and a building's passes are both generated with: seed, generator config, worker
    processes, overwrite and progress."""
    return dict(seed=args.seed, config=config, workers=args.workers, overwrite=args.overwrite, progress=not args.quiet)


def _building(
    args: GenerateSettings, spec: LayoutSpec, given: dict[str, int], config: object, tasks: TaskMap | None
) -> int:
    """``--building [FILE]``: every pass of a building (`waresynth.building.generate`); a rescan takes SCAN's
    image size and layout spec where the options are not given, and refuses those given that differ."""
    from waresynth.building.generate import generate_building

    if args.building:
        from layouts.publish import refuse_overlap

        if Path(args.building).exists():
            refuse_overlap([args.out], {"--building": args.building}, "OUT")
    root = generate_building(
        args.out,
        building=args.building or None,
        image_size=None if args.size is None else (args.size, args.size),
        spec=spec if args.rescan is None else given,
        rescan=args.rescan,
        tasks=tasks,
        **_written(args, config),
    )
    from waresynth.dataset import open_dataset

    ds = open_dataset(root)
    passes = ds.sequences()
    frames = sum(s.num_frames for s in passes)
    what = "" if args.rescan is None else f" (a rescan of {args.rescan}: ground_truth/changes.csv)"
    print(
        f"{root}: a building of {len(passes)} passes ({frames} frames){what}, images "
        f"{ds.image_size[0]}x{ds.image_size[1]}, layouts {ds.spec.shape}; route.json, ground_truth/building.json "
        "and inventory.csv beside them"
    )
    return 0
