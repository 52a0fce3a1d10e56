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


# --- lastmile eval: scoring against real data (self-contained block) --------------------------------
eval_app = typer.Typer(no_args_is_help=True, help="Score the stack's modules on real data sets.")
app.add_typer(eval_app, name="eval")


@eval_app.command("tracking")
def eval_tracking(
    detections: Annotated[Path, typer.Option(help="Directory holding pointrcnn_<Class>/<seq>.txt.")],
    labels: Annotated[Path, typer.Option(help="Directory holding KITTI tracking labels <seq>.txt.")],
    sequences: Annotated[
        str | None, typer.Option(help="Comma-separated sequences, e.g. 0000,0002 [default: all labels].")
    ] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the scores as JSON here.")] = None,
    results: Annotated[
        Path | None, typer.Option(help="Write the tracks as KITTI tracking results <seq>.txt here.")
    ] = None,
) -> None:
    """Track KITTI detections with aUToTrack and print CLEAR MOT and sAMOTA/AMOTA per class (3D IoU 0.25)."""
    import json

    from rich.console import Console
    from rich.table import Table

    try:
        from lastmile.evaluation.kitti_io import list_sequences, write_results
        from lastmile.runner.kitti_tracking import run_kitti

        seqs = [s.strip() for s in sequences.split(",") if s.strip()] if sequences else list_sequences(labels)
        if not seqs:
            raise ConfigError(f"--sequences: expected names like 0000,0002, got {sequences!r}")
        run_result = run_kitti(detections, labels, seqs)
        if results is not None:
            results.mkdir(parents=True, exist_ok=True)
            for name, rows in run_result.results.items():
                write_results(results / f"{name}.txt", rows)
    except LastmileError as exc:
        typer.echo(f"lastmile eval tracking: {exc}", err=True)
        raise typer.Exit(2) from None
    except OSError as exc:
        typer.echo(f"lastmile eval tracking: {exc}", err=True)
        raise typer.Exit(2) from None
    table = Table(title=f"aUToTrack on KITTI {', '.join(seqs)} (3D IoU 0.25)")
    for col in ("class", "sAMOTA", "AMOTA", "MOTA", "MOTP", "IDS", "FRAG", "FP", "FN"):
        table.add_column(col, justify="right")
    report: dict[str, object] = {}
    for cls, r in run_result.per_class.items():
        d = r.as_dict()
        report[cls] = {
            k: d[k] for k in ("samota", "amota", "mota", "motp", "id_switches", "fragmentations", "fp", "fn")
        }
        table.add_row(
            cls,
            *(
                f"{v:.4f}" if isinstance(v, float) else "n/a"
                for v in (d["samota"], d["amota"], d["mota"], d["motp"])
            ),
            *(str(d[k]) for k in ("id_switches", "fragmentations", "fp", "fn")),
        )
    report["frames"] = run_result.frames
    report["frames_per_second"] = run_result.frames_per_second
    Console().print(table)
    typer.echo(
        f"{run_result.frames} frames, {run_result.frames_per_second:.0f} frames/s (tracking only, one core)"
    )
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(report, indent=2))


def main() -> None:
    app()
