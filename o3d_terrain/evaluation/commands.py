"""The ``o3d-terrain eval`` sub-commands (argparse wiring; each handler returns an exit code).

``eval segmentation``  ground precision/recall/F1/obstacle recall on labelled frames
``eval terrain``       height RMSE and slope error against an exact terrain, with error maps
``eval deviation``     the paper's Sec. VI obstacle-deviation protocol (when available)

Handlers print the tables (this is the command-line layer) and write JSON/Markdown/PNG into
``--output``. Exit codes: 0 all frames evaluated, 1 some frame failed (the others are still
reported), 2 bad usage (raised as ConfigError and mapped by the CLI).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import yaml

from ..errors import ConfigError, InputError, Problem

EXIT_OK, EXIT_FAILURE = 0, 1


def add_eval_commands(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``eval`` with its sub-commands to the CLI's sub-parsers."""
    from .peers import PEERS

    evaluate = subparsers.add_parser(
        "eval", help="evaluate segmentation and terrain accuracy on labelled data",
        description="Evaluate ground segmentation and terrain accuracy.")
    sub = evaluate.add_subparsers(dest="eval_command", metavar="WHAT")
    evaluate.set_defaults(handler=lambda args: _missing_subcommand(evaluate))

    seg = sub.add_parser(
        "segmentation", help="ground precision, recall, F1 and obstacle recall per frame",
        description="Score ground segmentation on labelled frames: SemanticKITTI sequence "
                    "folders (velodyne/ + labels/) or folders of them, LAS/LAZ files or folders "
                    "(class 2 = ground), PLY/PCD clouds with a label attribute (with --labels "
                    "or --ground-labels), or synthetic:NAME[,NAME...][:stereo|:solid_state] "
                    "scenes.")
    seg.add_argument("datasets", nargs="+", metavar="DATASET")
    seg.add_argument("--method", "-m", action="append", default=[], metavar="NAME",
                     help="o3d_terrain (default) or a peer: " + ", ".join(PEERS)
                          + " (peers need the bench extra); repeat to compare")
    seg.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                     help="an option of segment_terrain, e.g. --option cell_size=0.25")
    seg.add_argument("--labels", metavar="NAME",
                     help="the label set that says which ids are ground: semantickitti, "
                          "rellis3d or asprs (default: the data's format: SemanticKITTI "
                          "folders semantickitti, RELLIS-3D's layout rellis3d, LAS asprs)")
    seg.add_argument("--ground-labels", metavar="IDS",
                     help="comma-separated label ids (LAS classes) that are ground, replacing "
                          "the label set's, e.g. 1,3,10")
    seg.add_argument("--ignore-labels", metavar="IDS",
                     help="comma-separated label ids that are not scored (replacing the set's)")
    seg.add_argument("--obstacle-labels", metavar="IDS",
                     help="comma-separated label ids that count for obstacle recall (replacing "
                          "the set's; 'all' = every scored label that is not ground)")
    seg.add_argument("--label-field", metavar="NAME",
                     help="the per-point label attribute of PLY/PCD clouds (default: the first "
                          "of label, labels, semantic, class, classification and CloudCompare's "
                          "scalar_ names present)")
    seg.add_argument("--limit", type=int, default=None, help="at most this many frames each")
    seg.add_argument("--seed", type=int, default=0, help="seed of the synthetic scenes")
    seg.add_argument("--output", "-o", metavar="DIR",
                     help="write segmentation.json and segmentation.md here")
    seg.add_argument("--json", action="store_true", help="print JSON instead of tables")
    seg.set_defaults(handler=run_segmentation_command)

    ter = sub.add_parser(
        "terrain", help="height RMSE and slope error against an exact terrain, with error maps",
        description="Fit the terrain and compare it with an exact one: synthetic:NAME[,NAME..]"
                    "[:stereo|:solid_state] scenes, a DEM raster (e.g. dem.tif, sampled "
                    "into clouds), or a measured point cloud with --truth DEM.tif (a surveyed "
                    "elevation raster of its area).")
    ter.add_argument("source", metavar="SOURCE")
    ter.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                     help="an option of fit_terrain, e.g. --option control_points=[25,25]")
    ter.add_argument("--seed", type=int, default=0)
    ter.add_argument("--dem-cell-size", type=float, default=1.0, help="DEM cell size (m)")
    ter.add_argument("--window", type=float, default=40.0, help="DEM window side (m)")
    ter.add_argument("--max-windows", type=int, default=16, help="DEM windows evaluated (0 = all)")
    ter.add_argument("--density", type=float, default=4.0, help="DEM sampling (points per m²)")
    ter.add_argument("--noise", type=float, default=0.02, help="height noise of DEM samples (m)")
    ter.add_argument("--obstacles", type=int, default=0, help="box obstacles per DEM window")
    ter.add_argument("--truth", metavar="DEM.tif",
                     help="a surveyed elevation raster, GeoTIFF or ESRI ASCII grid (.asc), or "
                          "a file of surveyed ground points (LAS/LAZ: its class 2), gridded at "
                          "--truth-cell-size (default 1 m) (metres, the cloud's coordinates "
                          "after --pose): SOURCE is then a point cloud file, fitted and compared")
    ter.add_argument("--truth-origin", type=float, nargs=2, metavar=("X", "Y"),
                     help="x, y of the raster's upper-left corner (instead of GeoTIFF tags)")
    ter.add_argument("--truth-cell-size", type=float, metavar="M",
                     help="the raster's cell size in metres (with --truth-origin); for ground "
                          "points the cell they are gridded at")
    ter.add_argument("--pose", metavar="FILE",
                     help="4x4 matrix (text) mapping the cloud's coordinates into the raster's")
    ter.add_argument("--support-distance", type=float, metavar="M",
                     help="score raster cells with a cloud point this close to the centre "
                          "(default: the larger of the raster cell and the fit grid cell)")
    ter.add_argument("--output", "-o", metavar="DIR",
                     help="write terrain.json, terrain.md and error-map PNGs here")
    ter.add_argument("--json", action="store_true", help="print JSON instead of tables")
    ter.set_defaults(handler=run_terrain_command)

    _add_deviation(sub)
    return evaluate


def _missing_subcommand(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def parse_options(pairs: list[str], where: str) -> dict[str, Any]:
    """``KEY=VALUE`` strings to a dict (values parsed as YAML: numbers, lists, booleans)."""
    options, problems = {}, []
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            problems.append(Problem(where, f"'{pair}' is not KEY=VALUE",
                                    "write e.g. --option cell_size=0.25"))
            continue
        try:
            options[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            problems.append(Problem(where, f"the value of '{key}' is not valid ({exc})"))
    if problems:
        raise ConfigError(problems)
    return options


def _check_option_names(options: dict[str, Any], function, where: str) -> None:
    import inspect

    accepted = [p for p in inspect.signature(function).parameters if p != "cloud"]
    from ..errors import did_you_mean

    problems = []
    for key in options:
        if key not in accepted:
            hint = did_you_mean(key, accepted)
            problems.append(Problem(where, f"unknown option '{key}'",
                                    hint or f"options: {', '.join(accepted)}"))
    if problems:
        raise ConfigError(problems)


def _option_values(make, options: dict[str, Any]):
    """``make(**options)``, a bad option value reported as usage (exit 2) against --option."""
    try:
        return make(**options)
    except InputError as exc:
        raise ConfigError(Problem("--option", str(exc),
                                  "fix the value, e.g. --option cell_size=0.25")) from exc


# ---------------------------------------------------------------------------------------------
# segmentation


def run_segmentation_command(args: argparse.Namespace) -> int:
    from .datasets import open_dataset
    from .segmentation import OURS, evaluate_segmentation, method_names, ours, resolve_method

    methods = args.method or [OURS]
    problems = [Problem("--method", f"unknown method '{m}'", f"choose from {', '.join(method_names())}")
                for m in methods if m not in method_names() and m != "ours"]
    options = parse_options(args.option, "--option")
    if options:
        from ..api import segment_terrain

        _check_option_names(options, segment_terrain, "--option")
    if problems:
        raise ConfigError(problems)
    if args.limit is not None and args.limit < 1:
        raise ConfigError(Problem("--limit", f"must be >= 1, got {args.limit}"))
    labels = _label_set(args)
    if labels is None:
        from .datasets import NAME_THE_LABELS, NO_ONTOLOGY, labelled_clouds

        clouds = [d for d in args.datasets if labelled_clouds(d)]
        if clouds:
            raise ConfigError(Problem("--labels", f"{clouds[0]}: {NO_ONTOLOGY}",
                                      NAME_THE_LABELS))
    if labels is not None and not args.json:
        print(f"label set {labels.describe()}", file=sys.stderr)
    # our options checked (names and values) before any data set is read
    ours_method = (_option_values(ours, options) if any(m in (OURS, "ours") for m in methods)
                   else None)
    reports = []
    for dataset in args.datasets:
        for method in methods:
            frames = open_dataset(dataset, seed=args.seed, limit=args.limit, labels=labels,
                                  label_field=args.label_field)
            if method in (OURS, "ours"):
                run: Any = ours_method
            else:
                resolve_method(method)  # fail early with the bench-extra message
                run = method
            if not args.json:
                print(f"evaluating {method} on {dataset} ...", file=sys.stderr)
            report = evaluate_segmentation(frames, run, dataset=str(dataset))
            report.method = OURS if method == "ours" else method
            reports.append(report)
            if not args.json:
                print(report.to_markdown())
                print()
    failed = any(r.failures for r in reports)
    if args.json:
        print(json.dumps([json.loads(r.to_json()) for r in reports], indent=2))
    if args.output:
        out = Path(args.output)
        out.mkdir(parents=True, exist_ok=True)
        (out / "segmentation.json").write_text(
            json.dumps([json.loads(r.to_json()) for r in reports], indent=2) + "\n")
        (out / "segmentation.md").write_text(
            "\n\n".join(r.to_markdown() for r in reports) + "\n")
        if not args.json:
            print(f"wrote {out / 'segmentation.json'} and {out / 'segmentation.md'}",
                  file=sys.stderr)
    return EXIT_FAILURE if failed else EXIT_OK


def _label_ids(text: str | None, option: str, *, allow_all: bool = False):
    """The ids of a comma-separated ``--*-labels`` value (None when not given; "all" = None
    as a value where ``allow_all``)."""
    if text is None:
        return None
    if allow_all and text.strip().lower() == "all":
        return "all"
    ids = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if not part.isdigit():
            raise ConfigError(Problem(option, f"'{part}' is not a label id",
                                      f"give non-negative integers separated by commas, "
                                      f"e.g. {option} 1,3,10"))
        ids.append(int(part))
    if not ids:
        raise ConfigError(Problem(option, "no label id given", f"e.g. {option} 1,3,10"))
    return tuple(ids)


def _label_set(args: argparse.Namespace):
    """The LabelSet of ``--labels`` and the ``--*-labels`` ids, None when none is given (each
    format's own set)."""
    from ..errors import InputError
    from .datasets import LABEL_SETS, LabelSet, label_set

    ground = _label_ids(args.ground_labels, "--ground-labels")
    ignored = _label_ids(args.ignore_labels, "--ignore-labels")
    obstacle = _label_ids(args.obstacle_labels, "--obstacle-labels", allow_all=True)
    if args.labels is None and ground is None and ignored is None and obstacle is None:
        return None
    if args.labels is None and ground is None:
        raise ConfigError(Problem(
            "--ignore-labels" if ignored is not None else "--obstacle-labels",
            "changes a label set, but none is named",
            "give --labels NAME (" + ", ".join(LABEL_SETS) + ") or --ground-labels IDS"))
    if args.labels is not None:
        try:
            base = label_set(args.labels)
        except InputError as exc:
            raise ConfigError(Problem("--labels", str(exc))) from exc
    try:
        if args.labels is None:  # obstacles: every scored label that is not ground, or those
            changed = LabelSet("custom", ground, ignored or (),
                               None if obstacle == "all" else obstacle)
        else:
            changed = base.with_ids(ground=ground, ignored=ignored, obstacle=obstacle)
    except InputError as exc:
        raise ConfigError(Problem("--ground-labels/--ignore-labels/--obstacle-labels",
                                  str(exc))) from exc
    return changed


# ---------------------------------------------------------------------------------------------
# terrain


def run_terrain_command(args: argparse.Namespace) -> int:
    from .terrain import (default_fitter, evaluate_dem_terrain, evaluate_synthetic_terrain,
                          write_error_map)

    options = parse_options(args.option, "--option")
    if options:
        from ..api import fit_terrain

        _check_option_names(options, fit_terrain, "--option")
    fitter = _option_values(default_fitter, options)
    source = str(args.source)
    truth_flags = [flag for flag, name in (("--truth-origin", "truth_origin"),
                                           ("--truth-cell-size", "truth_cell_size"),
                                           ("--pose", "pose"),
                                           ("--support-distance", "support_distance"))
                   if getattr(args, name, None) is not None]
    if getattr(args, "truth", None) is not None:
        report, maps = _terrain_against_truth(args, options)
    elif truth_flags:
        raise ConfigError([Problem(flag, "applies only with --truth",
                                   "add --truth DEM.tif, or leave it out") for flag in truth_flags])
    elif source.startswith("synthetic"):
        from .datasets import synthetic_scene_names

        parts = source.split(":")
        names = [n for n in (parts[1].split(",") if len(parts) > 1 else []) if n]
        if not names or names == ["all"]:
            names = list(synthetic_scene_names())
        sensor = parts[2] if len(parts) > 2 else "lidar"
        report = evaluate_synthetic_terrain(names, fitter, sensor=sensor, seed=args.seed)
        maps = {r.name: (r.height_error, r.slope_error, True) for r in report.results}
    else:
        path = Path(source)
        if not path.exists():
            raise ConfigError(Problem("SOURCE", f"{path}: no such file",
                                      "give a DEM raster (.tif) or synthetic:NAME"))
        report = evaluate_dem_terrain(
            path, fitter, cell_size=args.dem_cell_size, window=args.window,
            max_windows=args.max_windows or None, density=args.density, noise=args.noise,
            obstacles=args.obstacles, seed=args.seed)
        maps = {path.stem: (report.maps["height_error"], report.maps["slope_error"], False)}
    if args.json:
        print(report.to_json())
    else:
        print(report.to_markdown())
    if args.output:
        out = Path(args.output)
        out.mkdir(parents=True, exist_ok=True)
        (out / "terrain.json").write_text(report.to_json() + "\n")
        (out / "terrain.md").write_text(report.to_markdown() + "\n")
        for name, (height, slope, is_xy) in maps.items():
            write_error_map(out / f"error_map_{name}.png", height, slope, grid_is_xy=is_xy)
        if not args.json:
            print(f"wrote terrain.json, terrain.md and {len(maps)} error map(s) to {out}",
                  file=sys.stderr)
    return EXIT_FAILURE if report.failures else EXIT_OK


def _terrain_against_truth(args: argparse.Namespace, options: dict[str, Any]):
    """``eval terrain CLOUD --truth DEM.tif``: the report and its error map (raster window)."""
    from ..errors import InputError
    from ..io import CLOUD_EXTENSIONS, read_cloud
    from .terrain import TruthOverlapError, evaluate_terrain_against_raster, read_pose, read_raster

    cloud_path, truth_path = Path(args.source), Path(args.truth)
    problems = []
    if not cloud_path.is_file():
        problems.append(Problem("CLOUD", f"{cloud_path}: no such file",
                                f"give a point cloud file ({', '.join(CLOUD_EXTENSIONS)})"))
    if not truth_path.is_file():
        problems.append(Problem("--truth", f"{truth_path}: no such file",
                                "give an elevation raster (GeoTIFF, ESRI ASCII grid) or a file "
                                "of surveyed ground points"))
    # a raster's place needs both; ground points are gridded at --truth-cell-size alone
    truth_points = truth_path.suffix.lower() in CLOUD_EXTENSIONS
    no_cell = args.truth_origin is not None and args.truth_cell_size is None
    no_origin = args.truth_cell_size is not None and args.truth_origin is None
    if no_cell or (no_origin and not truth_points):
        problems.append(Problem("--truth-cell-size" if no_cell else "--truth-origin", "missing",
                                "give --truth-origin X Y and --truth-cell-size M together"))
    if args.truth_cell_size is not None and not args.truth_cell_size > 0:
        problems.append(Problem("--truth-cell-size", f"must be > 0 m, got {args.truth_cell_size}"))
    if args.support_distance is not None and not args.support_distance > 0:
        problems.append(Problem("--support-distance",
                                f"must be > 0 m, got {args.support_distance}"))
    if problems:
        raise ConfigError(problems)
    # each input, its errors named by its option
    steps = [("--pose", lambda: read_pose(args.pose) if args.pose else None),
             ("--truth", lambda: read_raster(truth_path, origin=args.truth_origin,
                                             cell_size=args.truth_cell_size)),
             ("CLOUD", lambda: read_cloud(cloud_path))]
    values = []
    for where, read in steps:
        try:
            values.append(read())
        except InputError as exc:
            problems.append(Problem(where, str(exc)))
    if problems:
        raise ConfigError(problems)
    pose, raster, cloud = values
    try:  # sensor_origin defaults to where the pose puts the cloud's origin
        report = evaluate_terrain_against_raster(
            cloud, raster, pose=pose, fit_options=options,
            support_distance=args.support_distance, name=cloud_path.stem)
    except TruthOverlapError as exc:
        raise ConfigError(Problem("--truth", str(exc))) from exc
    maps = {cloud_path.stem: (report.maps["height_error"], report.maps["slope_error"], False)}
    return report, maps


# ---------------------------------------------------------------------------------------------
# deviation (Sec. VI protocol, provided by o3d_terrain.deviation)


def _add_deviation(sub: argparse._SubParsersAction) -> None:
    try:
        from .. import deviation
    except ImportError:  # not in this build
        return
    dev = sub.add_parser(
        "deviation", help="the paper's Sec. VI protocol: surface deviation caused by an obstacle",
        description="Broggi et al. 2013 Sec. VI: flat road, one box obstacle at (11, 0) in a "
                    "22 m x 22 m area; maximum deviation of the fitted surface as a share of the "
                    "obstacle height, for each width, height, control-point count and method.")
    dev.add_argument("--widths", type=float, nargs="+", metavar="M",
                     help="obstacle widths in metres (default: the paper's)")
    dev.add_argument("--heights", type=float, nargs="+", metavar="M",
                     help="obstacle heights in metres (default: the paper's)")
    dev.add_argument("--control-points", type=int, nargs="+", metavar="N",
                     help="control points per axis to compare (default: 5 25)")
    dev.add_argument("--methods", nargs="+", metavar="NAME",
                     help="fitting methods (default: robust paper)")
    dev.add_argument("--cell-size", type=float, help="grid cell size in metres (default 0.5)")
    dev.add_argument("--output", "-o", metavar="DIR", default=None,
                     help="write the deviation table and plot here")
    dev.set_defaults(handler=run_deviation_command)
    del deviation


def run_deviation_command(args: argparse.Namespace) -> int:
    from .. import deviation

    options = {name: getattr(args, name) for name in
               ("widths", "heights", "control_points", "methods", "cell_size")
               if getattr(args, name, None) is not None}
    result = deviation.run_deviation_protocol(**options)
    print(result.table() if hasattr(result, "table") else result)
    if args.output:
        written = deviation.write_deviation_outputs(result, Path(args.output))
        print(f"wrote {len(written)} file(s) to {args.output}", file=sys.stderr)
    return EXIT_OK
