"""The ``lastmile`` command line."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import typer

from lastmile import __version__
from lastmile.core.errors import ConfigError, LastmileError

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
def replay(
    file: Annotated[Path, typer.Argument(help="Black-box MCAP file (or a spool directory of chunks).")],
    render: Annotated[
        Path | None, typer.Option(help="Render a top-down PNG sequence into this directory.")
    ] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of recorded time when rendering.")] = 10.0,
) -> None:
    """Summarise a black-box recording (channels, counts, time span, events); optionally render PNGs."""
    from rich.console import Console
    from rich.table import Table

    from lastmile.recorder.replay import read_recording, render_png_sequence

    try:
        if not fps > 0:
            raise ConfigError(f"--fps: expected a positive rate, got {fps}")
        rec = read_recording(file)
    except LastmileError as exc:
        typer.echo(f"lastmile replay: {exc}", err=True)
        raise typer.Exit(2) from None
    console = Console()
    first, last = rec.span_us
    table = Table(title=f"{file}: {len(rec.messages)} messages, {first / 1e6:.2f} s to {last / 1e6:.2f} s")
    for col in ("topic", "schema", "messages", "first [s]", "last [s]"):
        table.add_column(col, justify="right" if col in ("messages", "first [s]", "last [s]") else "left")
    for ch in rec.channels:
        table.add_row(
            ch.topic, ch.schema, str(ch.count), f"{ch.first_us / 1e6:.2f}", f"{ch.last_us / 1e6:.2f}"
        )
    console.print(table)
    for ev in rec.events:
        console.print(
            f"event: {ev.get('trigger')} at {int(ev.get('time_us', 0)) / 1e6:.2f} s: {ev.get('reason')}"
        )
    summary = rec.operator_summary
    console.print(f"operator summary: {summary}" if summary is not None else "operator summary: (none yet)")
    if render is not None:
        paths = render_png_sequence(rec, render, fps=fps)
        console.print(f"wrote {len(paths)} frames to {render}")


def main() -> None:
    app()
