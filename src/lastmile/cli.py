"""The ``lastmile`` command line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lastmile import __version__
from lastmile.core.errors import LastmileError
from lastmile.sim.weather import parse_weather

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Autonomous campus shuttle: stack, simulator, tools."
)


@app.command()
def version() -> None:
    """Print the installed version."""
    typer.echo(__version__)


@app.command()
def run(
    minutes: Annotated[float, typer.Option(help="Simulated minutes of service.")] = 10.0,
    seed: Annotated[int, typer.Option(help="Seed; one seed repeats a run bit for bit.")] = 0,
    weather: Annotated[str, typer.Option(help="clear, rain, snow or fog.")] = "clear",
    out: Annotated[Path, typer.Option(help="Run directory to write.")] = Path("runs/latest"),
    scenario: Annotated[Path | None, typer.Option(help="Scenario TOML file.")] = None,
) -> None:
    """Simulate the shuttle service in closed loop and write a run directory (in progress, issue #2)."""
    try:
        parse_weather(weather)
        if not minutes > 0:
            raise LastmileError(f"--minutes: expected a positive number, got {minutes}")
        if scenario is not None and not scenario.is_file():
            raise LastmileError(f"--scenario: expected a TOML file, got no such file {scenario}")
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    # Said plainly rather than faked: the runner that joins sim, stack and evaluation is not built yet.
    typer.echo("lastmile run: the closed-loop runner is not built yet (issue #2 in progress)", err=True)
    raise typer.Exit(3)


def main() -> None:
    app()
