"""The ``geofix`` command line: thin -- parse, call the public API, print or write.

Commands: ``demo``, ``run``, ``methods``, ``maps``, ``suitability``, ``export``,
``report``, ``grid``, ``replay``, ``serve``.
``geofix run`` is a contract relied on by outside scripts (flags and JSON keys are kept
exactly; they may be extended).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

from geofix.errors import GeofixError


class _OneLineErrors(TyperGroup):
    """The command group, with usage errors (a bad option value) printed in one line."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **kw):
        """Run the command line; a usage error prints ``error: ...`` and exits 2."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **kw)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **kw)
        except typer.Exit as exc:
            sys.exit(exc.exit_code)
        except typer.Abort:
            _print_line("interrupted:", "aborted")
            sys.exit(1)
        except Exception as exc:
            if not (hasattr(exc, "format_message") and hasattr(exc, "exit_code")):
                raise  # not a usage error (click's exception types are typer's own here)
            ctx = getattr(exc, "ctx", None)
            hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
            _print_line("error:", f"{exc.format_message()}{hint}")
            sys.exit(2 if ctx is not None or exc.exit_code == 2 else exc.exit_code)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=_OneLineErrors,
    add_completion=False,
    no_args_is_help=True,
    help="geofix: terrain- and gravity-aided navigation without GPS.",
)


def _version(show: bool) -> None:
    if show:
        from geofix._version import __version__

        print(f"geofix {__version__}")
        raise typer.Exit()


#: Width of the printed tables when stdout is not a terminal and ``COLUMNS`` is unset.
PIPED_WIDTH = 80


def _stdout_width() -> int | None:
    """The width of stdout's tables: the terminal's, else ``COLUMNS``, else 80 characters.

    Rich would otherwise take the width of stderr's or stdin's terminal for a piped stdout.
    """
    if sys.stdout.isatty() or os.environ.get("COLUMNS", "").isdigit():
        return None  # rich reads the terminal or COLUMNS
    return PIPED_WIDTH


_out = Console(width=_stdout_width())


def _say(*objects, **kw) -> None:
    """Print a message line on stdout, never wrapped (a path stays one piece to copy)."""
    _out.print(*objects, soft_wrap=True, **kw)


_err = Console(stderr=True)


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
    memory_budget: Annotated[
        str | None,
        typer.Option(
            help="Largest memory one command (or worker) may allocate: 2GiB, 500MB, 25% "
            "(of RAM). Default: GEOFIX_MEMORY_BUDGET, else half the RAM.",
        ),
    ] = None,
) -> None:
    """Geofix: terrain- and gravity-aided navigation without GPS."""
    if memory_budget is not None:
        from geofix.memory import ENV_VAR, parse_size

        def check():
            parse_size(memory_budget)
            os.environ[ENV_VAR] = memory_budget  # inherited by worker processes

        _guarded(check)


def _one_line(message: str) -> str:
    return " ".join(str(message).split())


def _print_line(prefix: str, message: str) -> None:
    """Print ``prefix message`` on one stderr line: plain text, never wrapped or parsed."""
    sys.stderr.write(f"{prefix} {_one_line(message)}\n")
    sys.stderr.flush()


def _fail(message: str) -> None:
    _print_line("error:", message)
    raise typer.Exit(code=2)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    _print_line("warning:", str(message))


RESUMABLE = "finished trials are stored; run the same command to resume"
"""What Ctrl-C prints for the commands that resume (``run``, ``demo``)."""
STOPPED = "stopped; outputs are whole or absent, run the command again"
"""What Ctrl-C prints for the other commands (their outputs are written whole or not)."""


def _guarded(fn, interrupted: str = STOPPED):
    """Run ``fn``; turn any error into one clear line on stderr and exit code 2.

    A :class:`GeofixError` prints its message; a MemoryError or an operating-system error
    (unwritable output, full disk) prints what failed; Ctrl-C prints ``interrupted``
    (:data:`RESUMABLE` for the commands that resume; exit 130). Anything else is a bug
    in geofix: it is reported in one line too, unless ``GEOFIX_DEBUG`` is set, which
    shows the traceback.
    """
    warnings.showwarning = _show_warning
    try:
        return fn()
    except GeofixError as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _block_interrupts()
        _print_line("interrupted:", interrupted)
        _leave_after_interrupt()
        raise typer.Exit(code=130) from None
    except MemoryError:
        _fail("out of memory (lower the sizes, or see --memory-budget)")
    except OSError as exc:
        where = f" {exc.filename}" if exc.filename else ""
        _fail(f"{exc.strerror or type(exc).__name__}:{where}")
    except (typer.Exit, typer.Abort):
        raise
    except Exception as exc:
        if os.environ.get("GEOFIX_DEBUG"):
            raise
        _fail(f"internal error {type(exc).__name__}: {exc} (set GEOFIX_DEBUG=1 for details)")


def _block_interrupts() -> None:
    """Block ``SIGINT`` in this thread (where signal masks exist): one Ctrl-C is enough."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def _leave_after_interrupt() -> None:
    """After a Ctrl-C with worker threads about: exit 130 at once.

    Every finished trial is committed and the workers are stopped by then. A normal
    interpreter exit would still join the process pool's manager thread, which a Ctrl-C
    landing inside the pool's own locking can leave waiting for ever. So the output is
    flushed and the process leaves without the joins. Without other threads (nothing to
    join) the normal exit follows.
    """
    if threading.active_count() <= 1:
        return
    with contextlib.suppress(OSError, ValueError):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(130)


@app.command()
def run(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML file.")],
    method: Annotated[
        list[str], typer.Option("--method", "-m", help="Method spec, e.g. 'tercom:metric=mad'.")
    ],
    trials: Annotated[int | None, typer.Option(help="Override the scenario's trials.")] = None,
    seed: Annotated[int | None, typer.Option(help="Override the scenario's seed.")] = None,
    jobs: Annotated[int | None, typer.Option(help="Worker processes (default: cores).")] = None,
    out: Annotated[Path, typer.Option(help="Output folder (results store, exports).")] = Path(
        "out"
    ),
    json_output: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout, nothing else.")
    ] = False,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address to run the campaign on.")
    ] = None,
    figure: Annotated[bool, typer.Option(help="Also write campaign.png to the output.")] = False,
    valid_bound: Annotated[
        bool,
        typer.Option(
            "--valid-bound",
            help="Also compute the valid bound max(CRLB, ZZB, genie) of every trial (slow).",
        ),
    ] = False,
) -> None:
    """Run a Monte Carlo campaign of one or more methods on a scenario."""

    def go():
        from geofix.console import ProgressBar
        from geofix.evaluate.campaign import run_campaign
        from geofix.sim.scenario import load_scenario

        scen = load_scenario(scenario)
        with ProgressBar(scen.name, enabled=not json_output or sys.stderr.isatty()) as bar:
            bar.phase(f"preparing the map, then {FIRST_TRIAL}")
            result = run_campaign(
                scen,
                method,
                trials=trials,
                seed=seed,
                jobs=jobs,
                out_dir=out,
                scheduler=scheduler,
                progress=bar,
                valid_bound=valid_bound,
            )
        if json_output:
            sys.stdout.write(json.dumps(result.summary.to_json()) + "\n")
            return
        _print_summary(result)
        if figure:
            _say(f"figure: {_write_figure(scen, result, out)}")

    _guarded(go, RESUMABLE)


FIRST_TRIAL = "the first trial (a first run also compiles the numerical kernels)"
"""What a campaign does before its first result: the progress line until the bar."""


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/demo"),
    trials: Annotated[int | None, typer.Option(help="Number of trials.")] = None,
    jobs: Annotated[int | None, typer.Option(help="Worker processes (default: cores).")] = None,
) -> None:
    """TERCOM and the point-mass filter beside the free INS on the Azores: table, figure."""

    def go():
        from geofix.console import ProgressBar
        from geofix.evaluate.campaign import campaign_map, run_campaign
        from geofix.sim.scenario import load_scenario

        scen = load_scenario(builtin_scenario("azores_demo"))
        methods = ["tercom", "pmf", "ins"]
        _say(
            f"[bold]{scen.name}[/]: TERCOM and the point-mass filter against the free INS "
            "on the bundled Azores bathymetry"
        )
        with ProgressBar(scen.name) as bar:
            bar.phase("preparing the map")
            campaign_map(scen)  # loads the map readers; the campaign's own call is then quick
            bar.phase(FIRST_TRIAL)
            result = run_campaign(
                scen, methods, trials=trials, jobs=jobs, out_dir=out, progress=bar
            )
        _print_summary(result)
        _say(f"figure: {_write_figure(scen, result, out)}")

    _guarded(go, RESUMABLE)


@app.command()
def methods(
    name: Annotated[
        str | None, typer.Argument(help="A method's name: show its settings one by one.")
    ] = None,
) -> None:
    """List the methods; with a NAME, every setting of that method with its default."""
    from geofix.methods import (
        available_methods,
        method_settings,
        method_summary,
        unknown_method_message,
    )
    from geofix.methods import setting_descriptions as describe

    known = available_methods()
    if name is None:
        table = Table(title="methods (geofix methods NAME shows one method's settings)")
        for col in ("name", "runs", "what it is"):
            table.add_column(col, overflow="fold")
        for key, cls in known.items():
            runs = "whole mission" if getattr(cls, "recursive", False) else "leg by leg"
            table.add_row(key, runs, method_summary(cls))
        _out.print(table)
        return
    if name not in known:
        _fail(unknown_method_message(name, known))
    cls = known[name]
    table = Table(title=f"{name}: {method_summary(cls)}")
    for col in ("setting", "default", "type", "what it does"):
        table.add_column(col, overflow="fold")
    notes = describe(cls)
    for setting, default, kind in method_settings(cls):
        table.add_row(setting, repr(default), kind, notes[setting])
    _out.print(table)
    _say(f"use as: --method '{name}:{_example_setting(cls)}'", highlight=False)


def _example_setting(cls) -> str:
    from geofix.methods import method_settings

    rows = method_settings(cls)
    return f"{rows[0][0]}={rows[0][1]}" if rows else ""


@app.command()
def maps() -> None:
    """List the bundled maps with their provenance (use them as 'builtin:NAME')."""
    from geofix.maps.bundled import bundled_maps

    table = Table(title="bundled maps")
    for col in ("name", "what", "source, licence"):
        table.add_column(col, overflow="fold")
    for name, info in bundled_maps().items():
        table.add_row(name, info.description, f"{info.source}; {info.licence}")
    _out.print(table)


@app.command()
def suitability(
    map_path: Annotated[str, typer.Argument(metavar="MAP", help="Map file or builtin:NAME.")],
    variable: Annotated[str | None, typer.Option(help="netCDF variable / band.")] = None,
    kind: Annotated[str | None, typer.Option(help="'depth' or 'gravity'.")] = None,
    region: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option(help="West east south north, in the file's coordinates."),
    ] = None,
    resample_m: Annotated[float | None, typer.Option(help="Cell size, metres.")] = None,
    window_cells: Annotated[
        int, typer.Option(help="Window side and standard-track length, cells.")
    ] = 21,
    noise_std: Annotated[
        float, typer.Option(help="Measurement noise 1-sigma for the CRLB, map units.")
    ] = 1.0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/suitability"),
) -> None:
    """Where can a vehicle fix its position? Window std, roughness and CRLB map and figure."""

    def go():
        import numpy as np

        from geofix.evaluate.suitability import require_relief, save_suitability
        from geofix.evaluate.suitability import suitability as compute
        from geofix.maps.io import load_grid
        from geofix.plot.suitability import save_suitability_figure

        _make_out_dir(out)
        grid = load_grid(
            map_path, variable=variable, kind=kind, region=region, resample_m=resample_m
        )
        result = compute(grid, window_cells=window_cells, noise_std=noise_std)
        require_relief(result)
        crlb = result.crlb.values[np.isfinite(result.crlb.values)]
        if crlb.size:
            q = np.percentile(crlb, [10, 50, 90])
            _say(
                f"{grid!r}: CRLB of a {window_cells}-sample track (worst heading) "
                f"p10 {q[0]:.3g} m, median {q[1]:.3g} m, p90 {q[2]:.3g} m"
            )
        paths = save_suitability(result, out)
        paths["figure"] = save_suitability_figure(result, out)
        for label, path in paths.items():
            _say(f"{label}: {path}")

    _guarded(go)


@app.command()
def export(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML file.")],
    out: Annotated[Path, typer.Option(help="Output netCDF file.")],
    trials: Annotated[int | None, typer.Option(help="Override the scenario's trials.")] = None,
    seed: Annotated[int | None, typer.Option(help="Override the scenario's seed.")] = None,
) -> None:
    """Write a scenario's exact trials (map, truth, INS, measurements) to netCDF."""

    def go():
        from geofix.sim.export import export_trials
        from geofix.sim.scenario import load_scenario

        path = export_trials(load_scenario(scenario), out, trials=trials, seed=seed)
        _say(f"trials: {path}")

    _guarded(go)


def _make_out_dir(out: Path) -> None:
    """Create the output folder now, before any work, or fail naming it."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GeofixError(f"cannot create --out folder {out}: {exc.strerror or exc}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise GeofixError(f"cannot write in --out folder {out} (permission denied)")


@app.command()
def report(
    out_dir: Annotated[Path, typer.Argument(help="Campaign folder written by geofix run --out.")],
    out: Annotated[
        Path | None, typer.Option(help="HTML file to write (default: OUT_DIR/report.html).")
    ] = None,
) -> None:
    """Write one self-contained HTML page of a campaign: tables, bound, settings, figures."""

    def go():
        from geofix.report import write_report

        _say(f"report: {write_report(out_dir, out)}")

    _guarded(go)


@app.command("grid")
def grid_command(
    soundings: Annotated[
        str, typer.Argument(help="GSF file, nav/soundings folder, soundings CSV/Parquet.")
    ],
    cell_m: Annotated[float, typer.Option("--cell-m", help="Cell size, metres.")],
    out: Annotated[Path, typer.Option(help="Output netCDF map (z, z_std, z_count).")],
    max_gap_cells: Annotated[
        float, typer.Option(help="Fill empty cells at most this many cells from data.")
    ] = 2.0,
    registration_std: Annotated[
        float | None,
        typer.Option(
            help="How well the soundings' positions register the map, metres (1-sigma per "
            "axis): kept as the map's registration_std_m, added to every reported covariance."
        ),
    ] = None,
) -> None:
    """Grid soundings to a netCDF map with an uncertainty layer (per-cell std and count)."""

    def go():
        from geofix.logs.gridmap import grid_log

        gridded, path = grid_log(
            soundings,
            cell_m,
            out,
            max_gap_cells=max_gap_cells,
            registration_std_m=registration_std,
        )
        filled = float((~np.isnan(gridded.grid.values)).mean())
        _say(f"{gridded.grid!r}: {filled:.0%} of cells with data; map: {path}")

    import numpy as np

    _guarded(go)


#: ``--registration-std`` of replay and serve: how well the primary map is registered.
RegistrationStd = Annotated[
    float | None,
    typer.Option(
        help="How well the map is registered, metres (1-sigma per axis): added to every "
        "reported covariance (over the map file's registration_std_m)."
    ),
]


#: ``--offset-std`` of replay and serve: each map's stated level, one per ``--map``.
OffsetStd = Annotated[
    list[float] | None,
    typer.Option(
        help="The 1-sigma of a map's level against its field's readings, map units: the "
        "prior of the filters' common offset (over the map file's offset_std); one per "
        "--map, in its order."
    ),
]


@app.command("replay")
def replay_command(
    log: Annotated[
        str, typer.Argument(help="GSF file, MGD77T .m77t, geofix export, nav/soundings folder.")
    ],
    method: Annotated[
        list[str], typer.Option("--method", "-m", help="Recursive method spec, e.g. 'pmf'.")
    ],
    map_path: Annotated[
        list[str] | None,
        typer.Option(
            "--map",
            help="Map file (default: an export's own map); one per --field, in its order, "
            "for several MGD77T fields.",
        ),
    ] = None,
    ins_initial_error_m: Annotated[
        float | None, typer.Option(help="Initial INS error simulated on a GNSS log, metres.")
    ] = None,
    ins: Annotated[
        Path | None, typer.Option(help="Scenario YAML whose ins: numbers drive the INS.")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the INS simulation and filters.")] = 0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/replay"),
    json_output: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout, nothing else.")
    ] = False,
    noise_std: Annotated[
        list[float] | None,
        typer.Option(
            help="Measurement noise 1-sigma per beam, map units; one per --field for several "
            "fields."
        ),
    ] = None,
    beams: Annotated[
        int | None, typer.Option(help="Beams of a ping used per update (default 64).")
    ] = None,
    trial: Annotated[int, typer.Option(help="Trial of a geofix export log.")] = 0,
    field: Annotated[
        list[str] | None,
        typer.Option(
            help="MGD77T channel: depth, gravity or magnetic (default depth); repeat it to "
            "weigh several in one filter (the first the primary), each with its --map."
        ),
    ] = None,
    segment: Annotated[
        int | None,
        typer.Option(help="MGD77T continuous segment of the field, from 0 (default longest)."),
    ] = None,
    start_h: Annotated[
        float | None, typer.Option(help="Replay from this many hours after the start.")
    ] = None,
    hours: Annotated[
        float | None, typer.Option(help="Replay this many hours (default: to the end).")
    ] = None,
    registration_std: RegistrationStd = None,
    offset_std: OffsetStd = None,
) -> None:
    """Replay a logged mission ping by ping through the online navigator."""

    def go():
        from geofix.replay import replay_log

        settings = {}
        stds = _field_noise(field or [], noise_std or [])
        if stds:
            settings["noise_std"] = stds[0]
        if beams is not None:
            settings["max_update_beams"] = beams
        result, paths = replay_log(
            log,
            map_path or None,
            method,
            ins,
            ins_initial_error_m,
            seed,
            out,
            settings,
            trial,
            field_name=field or None,
            segment=segment,
            start_h=start_h,
            hours=hours,
            field_noise_std=dict(zip((field or [])[1:], stds[1:], strict=False)),
            registration_std_m=registration_std,
            offset_std=offset_std or None,
        )
        if json_output:
            sys.stdout.write(json.dumps(result.summary) + "\n")
            return
        _print_replay(result.summary)
        for label, path in paths.items():
            _say(f"{label}: {path}")

    _guarded(go)


def _field_noise(fields: list[str], stds: list[float]) -> list[float]:
    """The ``--noise-std`` of a replay: none, one (the primary's) or one per ``--field``."""
    if len(stds) > 1 and len(stds) != len(fields):
        raise GeofixError(
            f"replay: give one --noise-std (the primary field's) or one per --field, in its "
            f"order (got {len(stds)} --noise-std and {len(fields)} --field)"
        )
    return list(stds)


#: The number columns of the replay table: (header, key of the replay summary).
REPLAY_COLUMNS = (
    ("end error m", "end_error_m"),
    ("converged NEES", "converged_nees"),
    ("mean error m", "mean_error_m"),
    ("max error m", "max_error_m"),
    ("converged at s", "converged_at_s"),
)


def _print_replay(summary: dict) -> None:
    """The replay's table: errors against the truth, the NEES of ``converged``, re-inits.

    ``converged NEES`` is the mean ``e^T C^-1 e`` over the pings reported ``converged``
    (:func:`geofix.replay.converged_nees`); ``-`` when none converged or without a truth.
    """
    table = Table(title=f"replay: {summary['pings']} pings")
    for col in ("method", *(head for head, _ in REPLAY_COLUMNS), "reinits"):
        table.add_column(col)
    for name, row in summary["methods"].items():
        cells = [row[key] for _, key in REPLAY_COLUMNS]
        table.add_row(name, *("-" if v is None else f"{v:.1f}" for v in cells), str(row["reinits"]))
    _out.print(table)


@app.command("serve")
def serve_command(
    map_path: Annotated[
        list[str],
        typer.Option(
            "--map",
            help="Map file or builtin:NAME; repeat it for a further field's map "
            "(a gravity or magnetic map beside the depth map: the first is the primary).",
        ),
    ],
    port: Annotated[int, typer.Option(help="TCP port.")],
    method: Annotated[str, typer.Option("--method", "-m", help="Recursive method spec.")] = "pmf",
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    seed: Annotated[int, typer.Option(help="Seed of every connection's navigator.")] = 0,
    noise_std: Annotated[
        float | None, typer.Option(help="Measurement noise 1-sigma per beam, map units.")
    ] = None,
    beams: Annotated[
        int | None, typer.Option(help="Beams of a ping used per update (default 64).")
    ] = None,
    variable: Annotated[str | None, typer.Option(help="netCDF variable / band.")] = None,
    resample_m: Annotated[float | None, typer.Option(help="Cell size, metres.")] = None,
    ins: Annotated[
        Path | None, typer.Option(help="Scenario YAML whose ins: numbers are the INS model.")
    ] = None,
    max_connections: Annotated[
        int | None, typer.Option(help="Connections served at once (default 256).")
    ] = None,
    max_line_bytes: Annotated[
        int | None, typer.Option(help="Longest request line, bytes (default 1 MiB).")
    ] = None,
    max_points: Annotated[
        int | None, typer.Option(help="Most particles or nodes of one connection's filter.")
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="Threads running updates (default 4).")
    ] = None,
    update_timeout_s: Annotated[
        float | None, typer.Option(help="Time budget of one update, seconds (default 60).")
    ] = None,
    registration_std: RegistrationStd = None,
    offset_std: OffsetStd = None,
) -> None:
    """Serve the navigator over TCP: newline-delimited JSON, one navigator per connection."""
    given = {
        "max_connections": max_connections,
        "max_line_bytes": max_line_bytes,
        "max_points": max_points,
        "workers": workers,
        "update_timeout_s": update_timeout_s,
    }

    def go():
        from geofix.maps.gridding import load_map_error
        from geofix.maps.io import load_grid
        from geofix.replay import (
            check_online_method,
            check_seed,
            check_settings,
            load_field_maps,
            load_ins_model,
            stated_levels,
        )
        from geofix.server import Session, serve
        from geofix.server_limits import ServerLimits

        limits = ServerLimits(**{k: v for k, v in given.items() if v is not None})
        check_seed(seed)
        check_settings({} if noise_std is None else {"noise_std": noise_std})
        check_online_method(method, "serve")
        primary, *further = map_path
        grid = load_grid(primary, variable=variable, resample_m=resample_m)
        if registration_std is not None:
            grid = grid.with_registration(registration_std)
        error = None if primary.startswith("builtin:") else load_map_error(primary)
        field_grids = load_field_maps(further, grid)
        if offset_std:
            levelled = stated_levels([grid, *field_grids], offset_std, "serve")
            grid, field_grids = levelled[0], tuple(levelled[1:])
        settings = {}
        if noise_std is not None:
            settings["noise_std"] = noise_std
        if beams is not None:
            settings["max_update_beams"] = beams
        ins_model = None if ins is None else load_ins_model(ins)
        # refuse early
        Session(grid, method, settings, seed, error, ins_model, field_grids=field_grids).close()
        maps = " + ".join(repr(g) for g in (grid, *field_grids))

        def announce(bound_host: str, bound_port: int) -> None:  # once listening: one line
            _print_line(
                "serving", f"{maps} with {method} on {bound_host}:{bound_port} (Ctrl-C stops)"
            )

        serve(
            grid,
            method,
            host,
            port,
            settings,
            seed,
            error,
            ins_model,
            limits,
            announce=announce,
            field_grids=field_grids,
        )

    try:
        _guarded(go, "server stopped")
    except OSError as exc:
        _fail(f"cannot listen on {host}:{port}: {exc.strerror or exc}")


def builtin_scenario(name: str) -> Path:
    """Path of a scenario shipped inside the package."""
    from geofix.sim.scenario import builtin_scenario_path

    return builtin_scenario_path(name)


def _print_summary(result) -> None:
    from geofix.console import summary_table

    _out.print(summary_table(result.summary, width=_out.width))
    for label, path in result.paths.items():
        _say(f"{label}: {path}")


def _write_figure(scen, result, out: Path) -> Path:
    """Write the campaign figure (:func:`geofix.plot.campaign.campaign_result_figure`)."""
    from geofix.plot.campaign import campaign_result_figure
    from geofix.plot.figures import save_figure

    return save_figure(campaign_result_figure(scen, result), Path(out) / "campaign.png")


def main() -> None:
    """Entry point for ``python -m geofix``."""
    app()


if __name__ == "__main__":
    main()
