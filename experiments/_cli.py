"""The one command-line runner of every ``python -m experiments.NAME`` entry point.

An entry point is a frozen config dataclass (its fields and their docstrings are the options and their
``--help``; its ``__post_init__`` validates them) and a ``main(config)``::

    if __name__ == "__main__":
        _cli.run(main, Config, description=__doc__)

:func:`run` configures the runtime before any computation, parses the options with tyro, and turns every
failure into one line ``prog: error: message`` with exit status 2 (``--debug``: the traceback instead).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sys
import traceback
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import NoReturn, TypeVar

import tyro
from tqdm import tqdm

import geometry
import mocap

from ._run_folder import run_folder as run_folder

__all__ = ["clips_option", "parse", "run", "run_folder", "stages"]

C = TypeVar("C")

DEBUG_HELP = "Every command also takes --debug: on an error, show the full traceback instead of one line."

def _one_line(tyro_message: str) -> str:
    """tyro's boxed error message on one line: each section of the box (its parts are separated by rules) in a few
    words, the unrecognised options first, the missing ones by name only (their help is in ``--help``)."""
    sections, current = [], []
    for line in tyro_message.splitlines():
        text = line.strip().strip("│╭╮╰╯").strip()
        if line.lstrip().startswith(("╭", "╰")) or (text and set(text) <= {"─", "-"}):  # box or plain rules
            if current:
                sections.append(current)
            current = []
        elif text:
            current.append(text)
    sections.append(current)
    said = []
    sections = [section for section in sections if section]
    if not tyro_message.lstrip().startswith("╭"):  # the plain layout puts the box's title ("Value error") first
        sections = sections[1:]
    for header, *rest in sections:
        if header.startswith("For full helptext"):
            continue
        if header.startswith("Unrecognized options"):  # "...:" alone, or with the one option on its line
            said.insert(0, f"unrecognised option(s): {' '.join([header.partition(':')[2].strip(), *rest]).strip()}")
        elif header.startswith("Missing from"):
            said.append(f"missing required option(s): {' '.join(l.split()[0] for l in rest if l.startswith('-'))}")
        else:
            said.append(" ".join([header, *rest]))
    return "; ".join(said) or tyro_message.strip()


def _fail(prog: str, message: str) -> NoReturn:
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def clips_option(clips: Sequence[str], data_root: str | os.PathLike | None) -> tuple[str, ...]:
    """A ``--clips`` option's clips with every file as a path that exists (:func:`mocap.resolve_clip`; relative ones
    found under the data folder, :func:`mocap.find_data_root`); a ValueError naming the option otherwise."""
    root = mocap.find_data_root(data_root)
    try:
        return tuple(mocap.resolve_clip(clip, root) for clip in clips)
    except ValueError as error:
        raise ValueError(f"--clips {error}" + ("" if root else " (relative paths need --data-root)")) from None


def expmap_clips(data_root: str | os.PathLike | None, split: str) -> tuple[str, ...]:
    """The CMU-Mocap benchmark's ``split`` files (:func:`mocap.cmu_expmap_files`) as absolute paths, so that caches
    keyed on clip names do not depend on the working folder."""
    return tuple(str(path.resolve()) for path in mocap.cmu_expmap_files(data_root, split))


def jsonl_log(out: Path) -> Callable[[dict], None]:
    """``log(record)``: appends ``record`` as one JSON line to ``out/log.jsonl``, the file opened for each record so
    that every line written survives a kill."""

    def log(record: dict) -> None:
        with (out / "log.jsonl").open("a") as stream:
            stream.write(json.dumps(record) + "\n")

    return log


@contextlib.contextmanager
def stages(out: Path, desc: str, names: Sequence[str]
           ) -> Iterator[tuple[Callable[[dict], None], Callable[[str], None]]]:
    """A staged run's JSON-lines log and progress bar: yields ``log(event)``, which appends the event to
    ``out/log.jsonl``, and ``progress(stage)``, which completes the previous stage on a bar over ``names`` and shows
    ``stage``; the last stage completes when the block does. The bar is closed on an error too, so that the one-line
    error starts a line of its own."""

    log = jsonl_log(out)
    with tqdm(total=len(names), desc=desc, unit="stage") as bar:
        started = []

        def progress(stage: str) -> None:
            if started:  # the running stage is done
                bar.update(1)
            started.append(stage)
            bar.set_postfix_str(stage)

        yield log, progress
        bar.update(1)


@contextlib.contextmanager
def _wide_terminal() -> Iterator[None]:
    """``COLUMNS`` set wide for the block (tyro and rich read it), then restored."""
    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100000"
    try:
        yield
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved


def _rename_aliases(argv: Sequence[str], aliases: Mapping[str, str]) -> list[str]:
    """``argv`` with each old option name (``--old`` or ``--old=value``) replaced by its current name."""
    renamed = []
    for arg in argv:
        name, equals, value = arg.partition("=")
        renamed.append(aliases[name] + equals + value if name in aliases else arg)
    return renamed


def _prog(main: Callable) -> str:
    return f"python -m experiments.{Path(sys.modules[main.__module__].__file__).stem}"


def parse(config_type: type[C], argv: Sequence[str], *, prog: str, description: str | None = None,
          aliases: Mapping[str, str] | None = None, debug: bool = False) -> C:
    """The ``config_type`` that ``argv`` (without ``--debug``) describes; ``--help`` exits 0 and a bad option
    exits 2 with one line ``prog: error: ...`` on stderr (``debug``: tyro's full message and traceback too).
    ``aliases``: old option names still accepted, mapped to their current names."""
    description = f"{description or ''}\n\n{DEBUG_HELP}".strip()
    args = _rename_aliases(argv, aliases or {})
    captured = io.StringIO()
    try:
        # tyro boxes its messages at the terminal's width and would break a long path inside an error in two: a
        # wide terminal keeps every line of the box whole for _one_line.
        with contextlib.redirect_stderr(captured), contextlib.redirect_stdout(io.StringIO()), _wide_terminal():
            config = tyro.cli(config_type, args=args, prog=prog, description=description)
    except SystemExit as exit_:
        if exit_.code in (0, None):  # --help: shown again, at the terminal's own width
            tyro.cli(config_type, args=args, prog=prog, description=description)
            raise
        if debug:
            sys.stderr.write(captured.getvalue())
        message = _one_line(captured.getvalue())
        # tyro reports a ValueError of a config's __post_init__ as "Error parsing <Config>: <its message>".
        refused, count = re.subn(r"^Error parsing (?!-)[\w.]+: ", "", message)
        _fail(prog, refused if count else f"{message} (see --help)")
    except ValueError as error:  # a config's __post_init__ refused an option
        if debug:
            traceback.print_exc()
        _fail(prog, str(error))
    sys.stderr.write(captured.getvalue())  # tyro's warnings, if any
    return config


def run(main: Callable[[C], object], config_type: type[C], *, description: str | None = None,
        float64: bool | Callable[[C], bool] = False, aliases: Mapping[str, str] | None = None,
        argv: Sequence[str] | None = None) -> NoReturn:
    """Parse ``argv`` (default ``sys.argv[1:]``) into a ``config_type`` (:func:`parse`), run ``main(config)``
    and exit.

    ``float64``: whether the run needs ``jax_enable_x64`` (a function of the config where an option decides);
    it is set explicitly either way, with XLA's faulty CPU fusion turned off, before ``main`` starts.
    Exit status: 0 on success, 2 for a bad option or any error (one line ``prog: error: ...`` on stderr;
    ``--debug``: the traceback instead), 130 when interrupted. Warnings print as one line ``prog: warning: ...``.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    prog = _prog(main)
    geometry.disable_faulty_cpu_fusion()
    config = parse(config_type, [arg for arg in argv if arg != "--debug"], prog=prog, description=description,
                   aliases=aliases, debug=debug)

    import jax

    jax.config.update("jax_enable_x64", float64(config) if callable(float64) else float64)
    # A warning to the user of a command reads like its errors: one line naming the command, not a source line.
    warnings.formatwarning = lambda message, category, *_, **__: f"{prog}: warning: {message}\n"
    try:
        status = main(config)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except Exception as error:  # noqa: BLE001 - every failure becomes one line; --debug shows where
        if debug:
            traceback.print_exc()
        message = str(error).strip().splitlines()[0] if str(error).strip() else ""
        if not isinstance(error, (ValueError, OSError)):  # say what kind of failure an unexpected one is
            message = f"{type(error).__name__}: {message}".rstrip(": ")
        _fail(prog, message + ("" if debug else " (rerun with --debug for the traceback)"))
    raise SystemExit(status if isinstance(status, int) else 0)
