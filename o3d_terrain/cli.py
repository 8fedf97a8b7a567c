"""The ``o3d-terrain`` command. The only module that prints or exits.

Exit codes: 0 success, 2 bad configuration or usage, 1 runtime failure.
"""

from __future__ import annotations

import argparse
import sys
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from . import __version__
from .docgen import describe_text, list_text
from ._malloc import keep_freed_memory
from .errors import (ConfigError, NotACloudError, O3DTerrainError, Problem, TerrainWarning,
                     did_you_mean)
from .pipeline import load_pipeline, unchecked_attributes
from .stages import STAGES
from .writers import WRITERS

EXIT_OK, EXIT_FAILURE, EXIT_CONFIG = 0, 1, 2


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="o3d-terrain",
        description="Rational B-spline terrain models, slope and ground/obstacle segmentation "
                    "for point clouds.",
    )
    parser.add_argument("--version", action="version", version=f"o3d-terrain {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="show timings and full tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser("run", help="run a pipeline file")
    run.add_argument("pipeline", nargs="?", help="pipeline YAML file")
    run.set_defaults(usage_error=run.error)  # argparse's usage and exit 2, for _pipeline_argument
    run.add_argument("--input", "-i", action="extend", nargs="+", default=[], metavar="PATH",
                     help="point cloud file(s) or folder(s) to run on instead of the file's "
                          "source; several (-i a.ply b.ply, a shell glob, or -i repeated) make a "
                          "batch: each input gets its own sub-folder, named after the file; -2, "
                          "-3, ... for repeated names")
    run.add_argument("--output", "-o", metavar="DIR", help="output folder (default: the file's "
                     "output_dir, else ./out)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                     help="override an option, e.g. --set stages.0.cell_size=0.25")
    run.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS)

    validate = sub.add_parser("validate", help="check a pipeline file without reading any point")
    validate.add_argument("pipeline")
    validate.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                          dest="overrides")
    validate.add_argument("--input", "-i", metavar="PATH")
    validate.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS)

    sub.add_parser("stages", help="list the stages and writers")
    describe = sub.add_parser("describe", help="options of a stage or writer")
    describe.add_argument("name")
    describe.add_argument("--markdown", action="store_true", help="print the docs page")
    sub.add_parser("warmup", help="compile and cache the numba kernels now (once per install "
                                  "and machine) instead of on the first call")

    try:  # evaluation commands (o3d_terrain.evaluation)
        from .evaluation.commands import add_eval_commands
    except ImportError:
        add_eval_commands = None
    if add_eval_commands is not None:
        add_eval_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    verbose = getattr(args, "verbose", False)
    if args.command is None:
        parser.print_help()
        return EXIT_CONFIG
    keep_freed_memory()  # this process runs frame after frame: o3d_terrain/_malloc.py
    _show_warnings_plainly()
    try:
        if args.command == "run":
            return _run(args, verbose)
        if args.command == "validate":
            pipeline = load_pipeline(args.pipeline, overrides=args.overrides, input_path=args.input)
            count = len(pipeline.stages)
            unchecked = unchecked_attributes(pipeline)
            print(f"{args.pipeline}: valid ({count} stage{'s' * (count != 1)}, "
                  f"{len(pipeline.outputs)} output{'s' * (len(pipeline.outputs) != 1)})"
                  + ("" if pipeline.source is not None else
                     "; it has no source: run it with --input CLOUD")
                  + ("" if not unchecked else
                     "; attributes the cloud itself must carry (checked when it is read): "
                     + "; ".join(unchecked)))
            return EXIT_OK
        if args.command == "stages":
            print(list_text())
            return EXIT_OK
        if args.command == "describe":
            return _describe(args)
        if args.command == "warmup":
            from .warmup import warm_up

            print(warm_up().summary())
            return EXIT_OK
        if hasattr(args, "handler"):
            return int(args.handler(args) or 0)
    except ConfigError as exc:
        _error(exc)
        return EXIT_CONFIG
    except O3DTerrainError as exc:
        _error(exc, verbose)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_FAILURE
    except Exception as exc:  # an unexpected failure: short message unless -v
        _error(exc, verbose, unexpected=True)
        return EXIT_FAILURE
    parser.print_help()
    return EXIT_CONFIG


def _error(exc: BaseException, verbose: bool = False, unexpected: bool = False) -> None:
    if verbose:
        traceback.print_exception(type(exc), exc, exc.__traceback__)
    prefix = "error" if not unexpected else f"error ({type(exc).__name__})"
    print(f"{prefix}: {exc}", file=sys.stderr)
    if unexpected and not verbose:
        print("(run with -v for the traceback)", file=sys.stderr)


def _show_warnings_plainly() -> None:
    """The library's warnings about the input (TerrainWarning) as "warning: ..." lines on
    standard error, like the command's errors, not with Python's file and line."""
    show = warnings.showwarning

    def plain(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, TerrainWarning):
            print(f"warning: {message}", file=sys.stderr if file is None else file)
        else:
            show(message, category, filename, lineno, file, line)

    warnings.showwarning = plain


#: the sub-folder of a KITTI sequence folder (``sequences/00``) that holds its scans
KITTI_SCANS = "velodyne"


@dataclass(frozen=True)
class _Input:
    """One input of ``run``: its path, and the folder given with ``--input`` it was found in
    (None for a file named on the command line)."""

    path: Path
    folder: Path | None = None

    def skipped(self, exc: BaseException) -> str | None:
        """The message for a file of a folder that holds no point cloud (a
        :class:`NotACloudError` about this file: a KITTI sequence's ``calib.txt`` or
        ``times.txt``), with the ``velodyne/`` folder to give instead when the folder has
        one; None for any other failure (a cloud file cut short is a cloud that failed)."""
        if (self.folder is None or not isinstance(exc, NotACloudError)
                or Path(exc.path).resolve() != self.path.resolve()):
            return None
        text = f"{self.path}: skipped, not a point cloud ({exc.reason})"
        if (self.folder / KITTI_SCANS).is_dir():
            text += (f"; {self.folder} looks like a KITTI sequence folder: pass its scans with "
                     f"--input {self.folder / KITTI_SCANS}")
        return text


def _expand_inputs(inputs: Sequence[str]) -> list[_Input]:
    from .io import CLOUD_EXTENSIONS

    found: list[_Input] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files = sorted(p for p in path.iterdir()
                           if p.is_file() and p.suffix.lower() in CLOUD_EXTENSIONS)
            if not files:
                scans = path / KITTI_SCANS
                raise ConfigError(Problem(
                    "--input", f"folder '{item}' has no point cloud files",
                    f"a KITTI sequence folder keeps its scans in {KITTI_SCANS}/: pass "
                    f"--input {scans}" if scans.is_dir() else
                    f"give a folder holding {', '.join(CLOUD_EXTENSIONS)} files"))
            found += [_Input(p, path) for p in files]
        else:
            found.append(_Input(path))
    return found


def _output_folders(inputs: Sequence[Path]) -> list[str]:
    """Each batch input's output sub-folder: its file name without the suffix, and where two
    inputs share it (000000.bin of two drives, scan.las beside scan.laz) -2, -3, ... after it
    for the later ones, so that no input's outputs overwrite another's."""
    taken: set[str] = set()
    folders = []
    for path in inputs:
        name, k = path.stem, 1
        while name in taken:
            k += 1
            name = f"{path.stem}-{k}"
        taken.add(name)
        folders.append(name)
    return folders


def _pipeline_argument(args: argparse.Namespace) -> None:
    """``run -i a.ply b.ply pipeline.yaml``: the inputs' list took the pipeline file (the
    option's values run to the next option); the one YAML file among them is the pipeline."""
    if args.pipeline is not None:
        return
    files = [item for item in args.input if Path(item).suffix.lower() in (".yaml", ".yml")]
    if len(files) != 1:
        args.usage_error("the following arguments are required: pipeline")
    args.pipeline = files[0]
    args.input = [item for item in args.input if item != files[0]]


def _run(args: argparse.Namespace, verbose: bool) -> int:
    from .io import file_attributes

    _pipeline_argument(args)
    inputs = _expand_inputs(args.input)
    if len(inputs) <= 1 and not any(item.folder for item in inputs):
        # no input, or one file named on the command line: its outputs in OUTPUT itself
        pipeline = load_pipeline(args.pipeline, overrides=args.overrides,
                                 input_path=inputs[0].path if inputs else None)
        output = args.output or pipeline.output_dir or "out"
        result = pipeline.run(output_dir=output)
        _report(result, verbose)
        return EXIT_OK
    # a batch (several inputs, or a folder's): each in OUTPUT/<its name>/; check the
    # configuration once, then keep going past a bad input
    paths = [item.path for item in inputs]
    existing = [p for p in paths if p.is_file()]
    # checked on a PLY or PCD input when there is one: what the writers name that another
    # format cannot carry fails that input alone (its own check below), not the batch
    checked = load_pipeline(args.pipeline, overrides=args.overrides, input_path=next(
        (p for p in existing if file_attributes(p) is None), (existing or paths)[0]))
    output = Path(args.output or checked.output_dir or "out")
    failed = []
    for item, folder in zip(inputs, _output_folders(paths)):
        path = item.path
        out = output / folder
        try:
            pipeline = load_pipeline(args.pipeline, overrides=args.overrides, input_path=path)
            result = pipeline.run(output_dir=out)
            print(f"{path}: ok ({result.seconds:.2f} s) -> {out}")
            if verbose:
                _report(result, verbose)
        except (O3DTerrainError, OSError, ValueError) as exc:
            failed.append(path)
            print(item.skipped(exc) or f"{path}: FAILED: {exc}", file=sys.stderr)
        except Exception as exc:  # noqa: BLE001 - the batch goes on; -v shows the traceback
            failed.append(path)
            print(f"{path}: FAILED ({type(exc).__name__}, an internal error; please report it "
                  f"with this input): {exc}", file=sys.stderr)
            if verbose:
                traceback.print_exc()
    print(f"{len(inputs) - len(failed)} of {len(inputs)} inputs done"
          + (f"; failed: {', '.join(str(p) for p in failed)}" if failed else ""))
    return EXIT_FAILURE if failed else EXIT_OK


def _report(result, verbose: bool) -> None:
    for note in result.frame.notes:
        print(f"note: {note}")
    if verbose:
        for name, seconds in result.timings.items():
            print(f"  {name}: {seconds * 1000:.1f} ms")
    for path in result.written:
        print(f"wrote {path}")
    print(f"done: {len(result.frame)} points in {result.seconds:.2f} s")


def _describe(args: argparse.Namespace) -> int:
    registry = {**STAGES, **WRITERS}
    # the name as any case writes it (gridquantize, GRIDQUANTIZE)
    name = {k.lower(): k for k in registry}.get(args.name.lower(), args.name)
    if name not in registry:
        hint = did_you_mean(args.name, list(registry))
        raise ConfigError(Problem("describe", f"unknown stage or writer '{args.name}'"
                                  + (f" ({hint})" if hint else ""),
                                  "run 'o3d-terrain stages' for the list"))
    print(describe_text(registry[name], markdown=args.markdown))
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
