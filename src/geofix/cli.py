"""The ``geofix`` command line: thin -- parse, call the public API, print or write.

Commands: ``demo``, ``run``, ``methods``, ``maps``, ``suitability``, ``export``.
``geofix run`` is a contract relied on by outside scripts (flags and JSON keys are kept
exactly; they may be extended).
"""

from __future__ import annotations

import json
import os
import sys
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
_out = Console(width=None if sys.stdout.isatty() else 160)
_err = Console(stderr=True)


@app.callback()
def _options(
    memory_budget: Annotated[
        str | None,
        typer.Option(
            help="Largest memory one command (or worker) may allocate: 2GiB, 500MB, 25% "
            "(of RAM). Default: GEOFIX_MEMORY_BUDGET, else half the RAM.",
        ),
    ] = None,
) -> None:
    """geofix: terrain- and gravity-aided navigation without GPS."""
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


def _guarded(fn):
    """Run ``fn``; turn any error into one clear line on stderr and exit code 2.

    A :class:`GeofixError` prints its message; a MemoryError or an operating-system error
    (unwritable output, full disk) prints what failed; Ctrl-C prints how to resume
    (exit 130). Anything else is a bug in geofix: it is reported in one line too, unless
    ``GEOFIX_DEBUG`` is set, which shows the traceback.
    """
    warnings.showwarning = _show_warning
    try:
        return fn()
    except GeofixError as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _print_line("interrupted:", "finished trials are stored; run the same command to resume")
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
) -> None:
    """Run a Monte Carlo campaign of one or more methods on a scenario."""

    def go():
        from geofix.evaluate.campaign import run_campaign
        from geofix.sim.scenario import load_scenario

        scen = load_scenario(scenario)
        result = run_campaign(
            scen,
            method,
            trials=trials,
            seed=seed,
            jobs=jobs,
            out_dir=out,
            scheduler=scheduler,
            progress=not json_output or sys.stderr.isatty(),
        )
        if json_output:
            sys.stdout.write(json.dumps(result.summary) + "\n")
            return
        _print_summary(result)
        if figure:
            _out.print(f"figure: {_write_figure(scen, method, result, out)}")

    _guarded(go)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/demo"),
    trials: Annotated[int | None, typer.Option(help="Number of trials.")] = None,
    jobs: Annotated[int | None, typer.Option(help="Worker processes (default: cores).")] = None,
) -> None:
    """TERCOM Monte Carlo on the bundled Azores bathymetry: table and figure."""

    def go():
        from geofix.evaluate.campaign import run_campaign
        from geofix.sim.scenario import load_scenario

        scen = load_scenario(builtin_scenario("azores_demo"))
        methods = ["tercom", "tercom:metric=mad"]
        _out.print(f"[bold]{scen.name}[/]: TERCOM on the bundled Azores bathymetry")
        result = run_campaign(scen, methods, trials=trials, jobs=jobs, out_dir=out)
        _print_summary(result)
        _out.print(f"figure: {_write_figure(scen, methods, result, out)}")

    _guarded(go)


@app.command()
def methods() -> None:
    """List every method with its settings and their defaults."""
    from geofix.match.registry import available_methods, method_settings

    for name, cls in available_methods().items():
        table = Table(title=f"{name} -- {(cls.__doc__ or '').strip().splitlines()[0]}")
        table.add_column("setting")
        table.add_column("default")
        table.add_column("type")
        for setting, default, kind in method_settings(cls):
            table.add_row(setting, repr(default), kind)
        _out.print(table)


@app.command()
def maps() -> None:
    """List the bundled maps with their provenance (use them as ``builtin:NAME``)."""
    from geofix.maps.bundled import bundled_maps

    table = Table(title="bundled maps")
    for col in ("name", "what", "source, licence"):
        table.add_column(col)
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

        _make_out_dir(out)
        grid = load_grid(
            map_path, variable=variable, kind=kind, region=region, resample_m=resample_m
        )
        result = compute(grid, window_cells=window_cells, noise_std=noise_std)
        require_relief(result)
        crlb = result.crlb.values[np.isfinite(result.crlb.values)]
        if crlb.size:
            q = np.percentile(crlb, [10, 50, 90])
            _out.print(
                f"{grid!r}: CRLB of a {window_cells}-sample track (worst heading) "
                f"p10 {q[0]:.3g} m, median {q[1]:.3g} m, p90 {q[2]:.3g} m"
            )
        for label, path in save_suitability(result, out).items():
            _out.print(f"{label}: {path}")

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
        _out.print(f"trials: {path}")

    _guarded(go)


def _make_out_dir(out: Path) -> None:
    """Create the output folder now, before any work, or fail naming it."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GeofixError(f"cannot create --out folder {out}: {exc.strerror or exc}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise GeofixError(f"cannot write in --out folder {out} (permission denied)")


def builtin_scenario(name: str) -> Path:
    """Path of a scenario shipped inside the package."""
    from geofix.sim.scenario import builtin_scenario_path

    return builtin_scenario_path(name)


def _print_summary(result) -> None:
    from geofix.evaluate.campaign import summary_table

    _out.print(summary_table(result.summary, width=_out.width))
    for label, path in result.paths.items():
        _out.print(f"{label}: {path}")


def _write_figure(scen, specs, result, out: Path) -> Path:
    """Figure of trial 0 (re-simulated, deterministic) and the campaign's error histograms."""
    import numpy as np

    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.match.registry import parse_method_spec
    from geofix.plot.figures import campaign_figure, save_figure
    from geofix.sim.simulate import prepare_map, simulate_trial

    grid = prepare_map(scen)
    trial = simulate_trial(scen, grid, 0)
    estimates = {
        spec: run_trial(
            parse_method_spec(spec), trial, grid, method_rng(scen.seed, 0, spec)
        ).estimate
        for spec in specs
    }
    frame = result.frame
    errors = {
        spec: np.asarray(frame.loc[frame["method"] == spec, "end_error_m"], dtype=float)
        for spec in specs
    }
    fig = campaign_figure(grid, trial.truth, trial.indicated, estimates, errors, title=scen.name)
    return save_figure(fig, Path(out) / "campaign.png")


def main() -> None:
    """Entry point for ``python -m geofix``."""
    app()


if __name__ == "__main__":
    main()
