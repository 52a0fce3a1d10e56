"""The ``lastmile`` command line."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import typer

from lastmile import __version__
from lastmile.core.errors import LastmileError

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Autonomous campus shuttle: stack, simulator, tools."
)


@app.command()
def version() -> None:
    """Print the installed version."""
    typer.echo(__version__)


@app.command()
def run(
    minutes: Annotated[float | None, typer.Option(help="Simulated minutes of service [default: 10].")] = None,
    seed: Annotated[
        int | None, typer.Option(help="Seed; one seed repeats a run bit for bit [default: 0].")
    ] = None,
    weather: Annotated[str | None, typer.Option(help="clear, rain, snow or fog [default: clear].")] = None,
    out: Annotated[Path, typer.Option(help="Run directory to write.")] = Path("runs/latest"),
    scenario: Annotated[
        Path | None, typer.Option(help="Scenario TOML file (default: the campus service).")
    ] = None,
) -> None:
    """Simulate the shuttle service in closed loop and write a run directory with report.md."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        from lastmile.runner.closed_loop import evaluate_run, run_scenario
        from lastmile.sim.scenario import default_service, load_scenario
        from lastmile.sim.weather import parse_weather

        spec = load_scenario(scenario) if scenario is not None else default_service()
        overrides: dict[str, object] = {}
        if minutes is not None:
            overrides["minutes"] = minutes
        if seed is not None:
            overrides["seed"] = seed
        if weather is not None:
            parse_weather(weather)
            overrides["weather"] = weather
        spec = dataclasses.replace(spec, **overrides)  # type: ignore[arg-type]
        with Progress(
            TextColumn("[bold]simulating[/bold] {task.description}"),
            BarColumn(),
            TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
            TimeElapsedColumn(),
        ) as bar:
            task = bar.add_task(f"{spec.name} seed {spec.seed} {spec.weather}", total=spec.minutes * 60.0)
            log = run_scenario(spec, progress=lambda done, total: bar.update(task, completed=done))
        metrics = evaluate_run(log, out)
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(
        f"wrote {out}/report.md: {metrics['distance_m']:.0f} m, {metrics['stops_served']} stops served, "
        f"{metrics['collisions_total']} collisions, {metrics['takeovers']} takeovers, "
        f"real-time factor {log.timing['realtime_factor']:.1f}x"
    )


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port.")] = 8080,
    db: Annotated[
        str | None, typer.Option(help="SQLAlchemy URL (postgresql://...); default: SQLite in --out.")
    ] = None,
    out: Annotated[Path, typer.Option(help="Directory for fleet.db and tokens.json.")] = Path("runs/serve"),
    runs: Annotated[Path, typer.Option(help="Recorded runs operators may browse.")] = Path("runs"),
    timetable_lead: Annotated[
        float,
        typer.Option(min=0.0, help="Hand timetable runs to shuttles this many s before departure; 0: off."),
    ] = 600.0,
) -> None:
    """Run the dispatch server (HTTP + WebSocket API, web dashboard) until interrupted."""
    import uvicorn

    from lastmile.fleet.server import ServerConfig, create_app
    from lastmile.fleet.storage import default_sqlite_url, make_engine

    try:
        url = db or default_sqlite_url(out)
        make_engine(url).dispose()  # a bad URL or a missing driver fails here, as one line
    except LastmileError as exc:
        typer.echo(f"lastmile serve: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(
        f"lastmile serve: http://{host}:{port}/ (database {url}; first-start tokens in {out}/tokens.json)"
    )
    uvicorn.run(
        create_app(ServerConfig(db_url=url, out_dir=out, runs_dir=runs, timetable_lead_s=timetable_lead)),
        host=host,
        port=port,
        log_level="warning",
        access_log=False,
    )


def main() -> None:
    app()
