"""The ``lastmile`` command line."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from lastmile import __version__
from lastmile.core.errors import ConfigError, LastmileError
from lastmile.core.perception_mode import PerceptionMode

if TYPE_CHECKING:
    from lastmile.runner.loop import LoopCallback
    from lastmile.runner.run_config import RunConfig

PLAIN_HELP = None
"""Help text is plain, not Rich markup: markup mode ate every ``[default: ...]`` the options wrote."""

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=PLAIN_HELP,
    help="Autonomous campus shuttle: stack, simulator, tools.",
)


PERCEPTION_OPTIONS = {"lidar": PerceptionMode.LIDAR_CAMERA_RADAR, "radar": PerceptionMode.RADAR_TRACKING}
"""``--perception`` values and the stack's perception modes they select."""


def _run_config(config: Path | None, perception: str | None, default_perception: PerceptionMode) -> RunConfig:
    """The run configuration of ``--config`` (or the default), with ``--perception`` applied."""
    from lastmile.runner.run_config import RunConfig, load_run_config

    base = load_run_config(config) if config is not None else RunConfig()
    if perception is None:
        return base if config is not None else base.with_perception(default_perception)
    if perception not in PERCEPTION_OPTIONS:
        raise ConfigError(f"--perception: expected one of {sorted(PERCEPTION_OPTIONS)}, got {perception!r}")
    return base.with_perception(PERCEPTION_OPTIONS[perception])


def _print_version(value: bool) -> None:
    if value:
        typer.echo(__version__)
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Autonomous campus shuttle: stack, simulator, tools."""


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
    fleet: Annotated[
        int | None, typer.Option(help="N shuttles in one world, dispatched by the server (needs --serve).")
    ] = None,
    serve: Annotated[
        bool, typer.Option(help="Start the dispatch server for the run and link every shuttle to it.")
    ] = False,
    demand: Annotated[
        float, typer.Option(help="--fleet: ride requests per hour per ordered stop pair (Poisson).")
    ] = 2.0,
    perception: Annotated[
        str | None,
        typer.Option(
            help="lidar: raw LiDAR sweeps + camera boxes + radar through the stack's perception; "
            "radar: the radars' object lists only (faster) [default: the configuration's, lidar]."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(help="Run configuration TOML: the vehicle software and the loop (default: built in)."),
    ] = None,
    black_box: Annotated[
        bool, typer.Option(help="Keep the 30 s black box and write it under OUT/recordings on incidents.")
    ] = True,
    route: Annotated[
        Path | None,
        typer.Option(help="Route file (TOML): serve its stops on its Lanelet2 map instead of the campus."),
    ] = None,
    live: Annotated[
        bool, typer.Option(help="Serve the run live to Foxglove (WebSocket), paced to the wall clock.")
    ] = False,
    live_port: Annotated[int, typer.Option(help="--live: the WebSocket port (on 127.0.0.1).")] = 8765,
    record_map: Annotated[
        Path | None,
        typer.Option(help="Record the run's LiDAR sweeps (a rig frame per 2 m) and poses for `map build`."),
    ] = None,
) -> None:
    """Simulate the shuttle service in closed loop and write a run directory with report.md."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    if fleet is not None or serve:
        scenario_given = scenario is not None or weather is not None
        _run_fleet(fleet, serve, minutes, seed, demand, out, scenario_given, route)
        return

    try:
        from lastmile.api import prepare_run
        from lastmile.core.output_dir import prepare_output_dir
        from lastmile.runner.closed_loop import evaluate_run, load_world_map, run_scenario
        from lastmile.runner.stop_signals import StopSignals

        run_config = _run_config(config, perception, PERCEPTION_OPTIONS["lidar"])
        if not black_box:
            run_config = dataclasses.replace(
                run_config, loop=dataclasses.replace(run_config.loop, black_box=False)
            )
        spec, run_config = prepare_run(
            scenario, run_config, minutes=minutes, seed=seed, weather=weather, route=route
        )
        world_map = load_world_map(spec.map)  # a bad route or map is found before the run, not after
        mapping = _map_recording(record_map, run_config)
        from lastmile.hdmap.map_check import kerbside_lines

        for line in kerbside_lines(world_map):  # stops the route build moved off a bend
            typer.echo(f"lastmile run: {line}", err=True)
        prepare_output_dir(out)
        with (
            StopSignals() as stop,
            Progress(
                TextColumn("[bold]simulating[/bold] {task.description}"),
                BarColumn(),
                TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                TimeElapsedColumn(),
            ) as bar,
        ):
            task = bar.add_task(f"{spec.name} seed {spec.seed} {spec.weather}", total=spec.minutes * 60.0)
            log = run_scenario(
                spec,
                run_config,
                progress=lambda done, total: bar.update(task, completed=done),
                black_box_dir=out / "recordings",
                live=("127.0.0.1", live_port) if live else None,
                on_live=lambda port: bar.console.print(f"live: connect Foxglove to ws://127.0.0.1:{port}"),
                stop=lambda: stop.requested,
                extra_callbacks=mapping,
            )
        metrics = evaluate_run(log, out, hdmap=world_map.hdmap)
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    if log.timing.get("interrupted"):
        typer.echo(
            f"lastmile run: interrupted; wrote the {metrics['duration_s']:.0f} s simulated so far to {out}",
            err=True,
        )
        raise typer.Exit(stop.exit_code or 130)
    typer.echo(
        f"wrote {out}/report.md: {metrics['distance_m']:.0f} m, {metrics['stops_served']} stops served, "
        f"{metrics['collisions_total']} collisions, {metrics['takeovers']} takeovers, "
        f"real-time factor {log.timing['realtime_factor']:.1f}x"
    )


def _run_fleet(
    fleet: int | None,
    serve: bool,
    minutes: float | None,
    seed: int | None,
    demand: float,
    out: Path,
    scenario_given: bool,
    route: Path | None,
) -> None:
    """``lastmile run --fleet N --serve [--route FILE]``: see :mod:`lastmile.runner.fleet_run`."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        if fleet is None or not serve:
            raise ConfigError(
                f"expected --fleet N together with --serve, got --fleet {fleet} and --serve {serve}"
            )
        if scenario_given:
            raise ConfigError(
                "--fleet: expected no --scenario or --weather (the fleet world is its own), got one"
            )
        from lastmile.core.output_dir import prepare_output_dir
        from lastmile.runner.fleet_config import FleetConfig
        from lastmile.runner.fleet_run import run_fleet
        from lastmile.runner.stop_signals import StopSignals

        config = FleetConfig(
            shuttles=fleet,
            minutes=minutes if minutes is not None else 10.0,
            seed=seed if seed is not None else 0,
            demand_per_pair_per_h=demand,
            route=str(route) if route is not None else "",
        )
        if route is not None:
            from lastmile.hdmap.service_route import load_route

            load_route(route)  # a bad route or map is one line here, before the server starts
        prepare_output_dir(out)
        with (
            StopSignals() as stop,
            Progress(
                TextColumn(f"[bold]simulating[/bold] {fleet} shuttles with the server"),
                BarColumn(),
                TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                TimeElapsedColumn(),
            ) as bar,
        ):
            task = bar.add_task("fleet", total=config.minutes * 60.0)
            m = run_fleet(
                config,
                out,
                progress=lambda done, total: bar.update(task, completed=done),
                stop=lambda: stop.requested,
            )
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    wait = m["wait_s"]["median"]
    typer.echo(
        f"wrote {out}/fleet_report.md: {m['requests_served']}/{m['requests_made']} requests served, "
        f"median wait {'-' if wait is None else f'{wait:.0f} s'}, "
        f"{m['fleet_distance_km']:.1f} km, real-time factor {m['timing']['realtime_factor']:.1f}x"
    )
    if m["interrupted"]:
        typer.echo(f"lastmile run: interrupted after {m['duration_s']:.0f} s simulated", err=True)
        raise typer.Exit(stop.exit_code or 130)


@app.command()
def sweep(
    suite: Annotated[str | None, typer.Option(help="A named suite: iso22737.")] = None,
    generate: Annotated[
        int | None, typer.Option(help="Generate this many scenarios from the scenario space.")
    ] = None,
    scenarios: Annotated[
        Path | None, typer.Option(help="A folder of scenario TOML files to run as they are.")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the suite or of the generator.")] = 0,
    engine: Annotated[str, typer.Option(help="local (process pool) or ray.")] = "local",
    workers: Annotated[int | None, typer.Option(help="Local worker processes [default: all cores].")] = None,
    ray_address: Annotated[
        str | None, typer.Option(help="Ray cluster address (default: start Ray on this machine).")
    ] = None,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/sweep"),
    perception: Annotated[
        str | None,
        typer.Option(
            help="radar (object lists, faster) or lidar (raw LiDAR + camera + radar) "
            "[default: the configuration's; radar without --config]."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(help="Run configuration TOML for every case (each suite case may set its speed)."),
    ] = None,
    route: Annotated[
        Path | None,
        typer.Option(help="--generate: run them on this route file's map, encounters on its own stretches."),
    ] = None,
) -> None:
    """Run many scenarios; writes summary.json, report.md and every scenario file under OUT."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        from lastmile.core.output_dir import prepare_output_dir
        from lastmile.evaluation.sweep_report import write_sweep_report
        from lastmile.runner.stop_signals import StopSignals
        from lastmile.runner.sweep import ENGINES, check_cases, generic_cases, run_sweep
        from lastmile.sim.scenario import load_scenario
        from lastmile.sim.scenario_generator import ScenarioSpace, sample_scenarios
        from lastmile.sim.suites import SUITES

        run_config = _run_config(config, perception, PERCEPTION_OPTIONS["radar"])
        if seed < 0:
            raise ConfigError(f"sweep --seed: expected a non-negative integer, got {seed}")
        if engine not in ENGINES:
            raise ConfigError(f"sweep --engine: expected one of {', '.join(ENGINES)}, got {engine!r}")
        if route is not None and generate is None:
            raise ConfigError(
                "sweep --route: expected it with --generate (a suite is the campus's; scenario files "
                "name their own map), got it without"
            )
        chosen = [x for x in (suite, generate, scenarios) if x is not None]
        if len(chosen) != 1:
            raise ConfigError(
                f"sweep: expected exactly one of --suite, --generate, --scenarios, got {len(chosen)}"
            )
        if suite is not None:
            if suite not in SUITES:
                raise ConfigError(f"sweep --suite: expected one of {sorted(SUITES)}, got {suite!r}")
            cases = SUITES[suite](seed)
            title = f"Sweep: suite {suite} (seed {seed})"
        elif generate is not None:
            if generate < 1:
                raise ConfigError(f"sweep --generate: expected at least 1 scenario, got {generate}")
            space = ScenarioSpace(route=str(route) if route is not None else "")
            cases = generic_cases(sample_scenarios(space, generate, seed))
            title = f"Sweep: {generate} generated scenarios (seed {seed})"
        else:
            assert scenarios is not None
            if not scenarios.is_dir():
                raise ConfigError(
                    f"sweep --scenarios: expected a folder of scenario TOML files, got {str(scenarios)!r} "
                    f"({'a file' if scenarios.exists() else 'no such folder'})"
                )
            files = sorted(scenarios.glob("*.toml"))
            if not files:
                raise ConfigError(f"sweep --scenarios: expected TOML files in {scenarios}, got none")
            cases = generic_cases([load_scenario(f) for f in files], group=str(scenarios))
            title = f"Sweep: {len(files)} scenarios from {scenarios}"
        if workers is not None and workers < 1:
            raise ConfigError(f"sweep --workers: expected at least 1 worker process, got {workers}")
        check_cases(cases)
        prepare_output_dir(out)
        with (
            StopSignals() as stop,
            Progress(
                TextColumn("[bold]sweep[/bold]"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
            ) as bar,
        ):
            task = bar.add_task("scenarios", total=len(cases))
            summary = run_sweep(
                cases,
                out,
                engine=engine,
                workers=workers,
                ray_address=ray_address,
                progress=lambda done, total: bar.update(task, completed=done),
                config=run_config,
                stop=lambda: stop.requested,
            )
        report = write_sweep_report(summary, out, title)
    except LastmileError as exc:
        typer.echo(f"lastmile sweep: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(
        f"wrote {report}: {summary['passed']}/{summary['scenarios']} passed, "
        f"{summary['collisions_at_fault']} at-fault collisions"
    )
    if summary["interrupted"]:
        typer.echo(f"lastmile sweep: interrupted; {len(summary['not_run'])} scenarios not run", err=True)
        raise typer.Exit(stop.exit_code or 130)


experiment_app = typer.Typer(
    no_args_is_help=True, rich_markup_mode=PLAIN_HELP, help="Reproduce the papers' experiments."
)
app.add_typer(experiment_app, name="experiment")


@experiment_app.command("v2i")
def experiment_v2i(
    laps: Annotated[int, typer.Option(help="Laps per vehicle.")] = 20,
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds to average over.")] = "0,1,2",
    rate_hz: Annotated[float, typer.Option(help="Crossing camera broadcast rate (NUS: 5 or 1).")] = 5.0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/v2i"),
) -> None:
    """NUS's infrastructure-sensor experiment: time gained at a crossing against laps (Fig. 12)."""
    import json

    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    try:
        from lastmile.core.output_dir import prepare_output_dir
        from lastmile.evaluation.v2i_report import write_v2i_report
        from lastmile.sim.infrastructure import CrossingCameraConfig
        from lastmile.sim.v2i_experiment import V2iConfig, run_v2i_experiment

        try:
            seed_list = tuple(int(x) for x in seeds.split(","))
        except ValueError:
            raise ConfigError(
                f"experiment v2i --seeds: expected integers like 0,1,2, got {seeds!r}"
            ) from None
        if laps < 1:
            raise ConfigError(f"experiment v2i --laps: expected at least 1, got {laps}")
        if any(s < 0 for s in seed_list):
            raise ConfigError(f"experiment v2i --seeds: expected non-negative integers, got {seeds!r}")
        prepare_output_dir(out)
        config = V2iConfig(camera=CrossingCameraConfig(rate_hz=rate_hz))
        with Progress(SpinnerColumn(), TextColumn("[bold]v2i[/bold] simulating"), TimeElapsedColumn()) as bar:
            bar.add_task("v2i")
            result = run_v2i_experiment(config, laps=laps, seeds=seed_list)
        data = {
            "laps": result.laps,
            "rate_hz": result.rate_hz,
            "seeds": list(result.seeds),
            "rows": [
                {
                    "speed_mps": speed,
                    "vehicles": n,
                    "cumulative_gain_s": gain,
                    "mean_lap_base_s": result.mean_lap_base_s[(speed, n)],
                    "mean_lap_infra_s": result.mean_lap_infra_s[(speed, n)],
                }
                for (speed, n), gain in result.cumulative_gain_s.items()
            ],
        }
        out.mkdir(parents=True, exist_ok=True)
        (out / "v2i.json").write_text(json.dumps(data, indent=2))
        report = write_v2i_report(data, out)
    except LastmileError as exc:
        typer.echo(f"lastmile experiment v2i: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(f"wrote {report} and {out / 'fig12.png'}")


@app.command()
def replay(
    file: Annotated[Path, typer.Argument(help="Black-box MCAP file (or a spool directory of chunks).")],
    render: Annotated[
        Path | None,
        typer.Option(help="Draw the scene top-down: FILE.png for one picture, else a directory of frames."),
    ] = None,
    at: Annotated[
        float | None, typer.Option(help="Time (s) of the one picture [default: the first trigger].")
    ] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of recorded time when rendering.")] = 10.0,
    through_stack: Annotated[
        bool, typer.Option(help="Re-run the stack on the recorded inputs; say where its output differs.")
    ] = False,
    summary: Annotated[
        str | None, typer.Option(help="Attach the operator's written summary to the file (MCAP attachment).")
    ] = None,
    audio: Annotated[
        Path | None, typer.Option(help="--summary: attach the spoken summary too (.wav, .mp3, .ogg, .flac).")
    ] = None,
) -> None:
    """Summarise a recording (channels, counts, time span, events); optionally render it top-down."""
    from rich.console import Console
    from rich.table import Table

    from lastmile.recorder.replay import read_recording
    from lastmile.recorder.replay_render import render_png, render_png_sequence

    try:
        if not fps > 0:
            raise ConfigError(f"--fps: expected a positive rate, got {fps}")
        if render is not None and render.exists() and not render.is_dir():
            raise ConfigError(f"--render: expected a new file, got {render}, which exists (not overwritten)")
        if summary is not None or audio is not None:
            from lastmile.recorder.black_box import attach_operator_summary

            attach_operator_summary(file, summary, audio)
        rec = read_recording(file)
    except LastmileError as exc:
        typer.echo(f"lastmile replay: {exc}", err=True)
        raise typer.Exit(2) from None
    if rec.warning is not None:
        typer.echo(f"lastmile replay: warning: {rec.warning}", err=True)
    console = Console(width=140)
    first, last = rec.span_us
    total = sum(ch.count for ch in rec.channels)
    table = Table(title=f"{file}: {total} messages, {first / 1e6:.2f} s to {last / 1e6:.2f} s")
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
    try:
        if through_stack:
            from lastmile.runner.replay_through_stack import describe, replay_through_stack

            console.print(describe(replay_through_stack(rec)))
        if render is None:
            return
        if render.suffix.lower() == ".png":
            shot = render_png(rec, render, at_us=None if at is None else round(at * 1e6))
            console.print(
                f"wrote {render}: t = {shot.t_us / 1e6:.2f} s in {shot.fixed_frame}, ego "
                f"{'drawn' if shot.ego else 'unknown'}, {shot.boxes} boxes, {shot.cloud_points} points, "
                f"{shot.lines} path lines"
            )
        else:
            paths = render_png_sequence(rec, render, fps=fps)
            console.print(f"wrote {len(paths)} frames to {render}")
    except LastmileError as exc:
        typer.echo(f"lastmile replay: {exc}", err=True)
        raise typer.Exit(2) from None


# --- lastmile eval: scoring against real data (self-contained block) --------------------------------
eval_app = typer.Typer(
    no_args_is_help=True, rich_markup_mode=PLAIN_HELP, help="Score the stack's modules on real data sets."
)
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
    track_score: Annotated[
        str | None, typer.Option(help="Published track score: last (default), evidence, mean, refined.")
    ] = None,
) -> None:
    """Track KITTI detections with aUToTrack and print CLEAR MOT and sAMOTA/AMOTA per class (3D IoU 0.25)."""
    import json

    from rich.console import Console
    from rich.table import Table

    try:
        from lastmile.core.output_dir import prepare_output_dir, prepare_output_file
        from lastmile.evaluation.kitti_io import list_sequences, write_results
        from lastmile.runner.kitti_tracking import run_kitti
        from lastmile.tracking.autotrack import AutoTrackConfig

        tracker = AutoTrackConfig(track_score=track_score) if track_score is not None else None
        if results is not None:
            prepare_output_dir(results, "--results")
        if json_out is not None:
            prepare_output_file(json_out, "--json")

        seqs = [s.strip() for s in sequences.split(",") if s.strip()] if sequences else list_sequences(labels)
        if not seqs:
            raise ConfigError(f"--sequences: expected names like 0000,0002, got {sequences!r}")
        run_result = run_kitti(detections, labels, seqs, tracker)
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


@eval_app.command("localization")
def eval_localization(
    inputs: Annotated[
        list[Path],
        typer.Argument(help="Drive files: RTKLIB .pos, NMEA, CSV, ROS 1 .bag, rosbag2 (.mcap/.db3/dir)."),
    ],
    outage: Annotated[
        list[str] | None,
        typer.Option(help="Drop GNSS from START for DURATION s (START:DURATION), repeatable."),
    ] = None,
    mode: Annotated[str, typer.Option(help="Localization mode: ekf or dead_reckoning.")] = "ekf",
    lever_arm: Annotated[
        str, typer.Option(help="GNSS antenna from the rear axle: FORWARD,LEFT in m.")
    ] = "0,0",
    imu_grade: Annotated[
        str, typer.Option(help="IMU error model: consumer_mems or industrial_mems (datasheet figures).")
    ] = "consumer_mems",
    imu_forward_axis: Annotated[
        str, typer.Option(help="IMU axis pointing forward in a bag: x, -y, ...")
    ] = "x",
    use_accel: Annotated[
        bool | None,
        typer.Option(help="Drive the speed with the accelerometer [default: only without wheel speed]."),
    ] = None,
    imu_topic: Annotated[
        str | None, typer.Option(help="sensor_msgs/Imu topic when a bag has several.")
    ] = None,
    fix_topic: Annotated[str | None, typer.Option(help="sensor_msgs/NavSatFix topic when several.")] = None,
    odom_topic: Annotated[str | None, typer.Option(help="nav_msgs/Odometry topic when several.")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the scores as JSON here.")] = None,
    tum_dir: Annotated[
        Path | None, typer.Option(help="Write estimate.tum and reference.tum here (for evo_ape).")
    ] = None,
) -> None:
    """Replay a recorded drive through a localization mode with GNSS outages; score it against the GNSS."""
    import json

    from rich.console import Console
    from rich.table import Table

    try:
        from lastmile.core.output_dir import prepare_output_dir, prepare_output_file
        from lastmile.localization.ekf import PoseEkfConfig
        from lastmile.recorder.drive_reader import read_drive
        from lastmile.recorder.drive_rosbag import BagTopics
        from lastmile.runner import localization_replay as lr

        modes = {m.value: m for m in lr.LocalizationMode}
        if mode not in modes:
            raise ConfigError(f"--mode: expected one of {', '.join(modes)}, got {mode!r}")
        lever = lever_arm.split(",")
        try:
            lever_m = (float(lever[0]), float(lever[1])) if len(lever) == 2 else None
        except ValueError:
            lever_m = None
        if lever_m is None:
            raise ConfigError(f"--lever-arm: expected FORWARD,LEFT in metres, got {lever_arm!r}")
        config = PoseEkfConfig(zero_slip_offset_m=0.0, antenna_lever_arm_m=lever_m).with_imu(imu_grade)
        outages = tuple(lr.Outage.parse(o) for o in outage or ())
        if json_out is not None:
            prepare_output_file(json_out, "--json")
        if tum_dir is not None:
            prepare_output_dir(tum_dir, "--tum-dir")
        drive = read_drive(list(inputs), BagTopics(imu_topic, fix_topic, odom_topic), imu_forward_axis)
        result = lr.replay_drive(drive, outages, modes[mode], config, use_accel)
        if tum_dir is not None:
            tum_dir.mkdir(parents=True, exist_ok=True)
            lr.write_tum(tum_dir / "estimate.tum", result.t_s, result.estimate_xy, result.estimate_yaw_rad)
            lr.write_tum(tum_dir / "reference.tum", result.t_s, result.reference_xy, result.estimate_yaw_rad)
        if json_out is not None:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(lr.result_json(result), indent=2))
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile eval localization: {exc}", err=True)
        raise typer.Exit(2) from None
    table = Table(
        title=f"{', '.join(drive.sources)}: {drive.duration_s:.0f} s, {len(drive.fixes)} GNSS fixes"
    )
    table.add_column("metric")
    table.add_column("value")
    for name, value in lr.summary_rows(result):
        table.add_row(name, value)
    Console(width=160).print(table)


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port.")] = 8080,
    db: Annotated[
        str | None,
        typer.Option(
            envvar="LASTMILE_FLEET_DB",
            help="SQLAlchemy URL (postgresql://...; the environment keeps a password out of ps); "
            "default: SQLite in --out.",
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Directory for fleet.db and tokens.json.")] = Path("runs/serve"),
    runs: Annotated[Path, typer.Option(help="Recorded runs operators may browse.")] = Path("runs"),
    timetable_lead: Annotated[
        float,
        typer.Option(min=0.0, help="Hand timetable runs to shuttles this many s before departure; 0: off."),
    ] = 600.0,
    route: Annotated[
        Path | None,
        typer.Option(help="Route file (TOML): dispatch on its loop and stops instead of the campus."),
    ] = None,
) -> None:
    """Run the dispatch server (HTTP + WebSocket API, web dashboard) until interrupted."""
    from lastmile.core.output_dir import prepare_output_dir
    from lastmile.fleet.serve_main import serve as serve_forever

    try:
        prepare_output_dir(out)
        serve_forever(
            host=host,
            port=port,
            db=db,
            out=out,
            runs=runs,
            timetable_lead_s=timetable_lead,
            announce=typer.echo,
            route=route,
        )
    except LastmileError as exc:
        typer.echo(f"lastmile serve: {exc}", err=True)
        raise typer.Exit(2) from None


map_app = typer.Typer(
    no_args_is_help=True,
    rich_markup_mode=PLAIN_HELP,
    help="Check maps and route files for a shuttle service.",
)
app.add_typer(map_app, name="map")


@map_app.command("check")
def map_check(
    map_file: Annotated[Path | None, typer.Argument(help="Lanelet2 .osm map (or give --route).")] = None,
    projector: Annotated[
        str | None,
        typer.Option(help="utm:LAT,LON | mgrs:GRID | mgrs (map_projector_info.yaml beside the map) | local."),
    ] = None,
    route: Annotated[Path | None, typer.Option(help="Route file (TOML): its map, stops and loop.")] = None,
    png: Annotated[Path, typer.Option(help="Where to write the picture of the map and route.")] = Path(
        "map_check.png"
    ),
) -> None:
    """Print what the map offers a shuttle service and what is missing; write a PNG of it."""
    from lastmile.hdmap.map_check import main_check

    try:
        code = main_check(map_file, projector, route, png)
    except LastmileError as exc:
        typer.echo(f"lastmile map check: {exc}", err=True)
        raise typer.Exit(2) from None
    if code:
        raise typer.Exit(code)


@app.command()
def perceive(
    files: Annotated[
        list[Path], typer.Argument(help="KITTI .bin, .pcd, .mcap files or rosbag2 directories.")
    ],
    config: Annotated[
        Path | None, typer.Option(help="TOML: [sensor] model, mount, fields; [pipeline]; topic.")
    ] = None,
    out: Annotated[Path, typer.Option(help="Directory for labels/, objects.mcap, timing.json.")] = Path(
        "runs/perceive"
    ),
    detector: Annotated[
        Path | None, typer.Option(help="A LiDAR detector .onnx model (BEV contract; [detector] in --config).")
    ] = None,
) -> None:
    """Run the LiDAR pipeline on point-cloud files: KITTI object labels, a Foxglove MCAP, timing."""
    from lastmile.perception.perceive import load_perceive_config, perceive_files, summary_lines

    try:
        frames = perceive_files(files, load_perceive_config(config, detector), out)
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile perceive: {exc}", err=True)
        raise typer.Exit(2) from None
    for line in summary_lines(frames):
        typer.echo(line)
    typer.echo(f"wrote {out / 'labels'}/, {out / 'objects.mcap'} and {out / 'timing.json'}")


@map_app.command("build")
def map_build(
    recording: Annotated[
        Path, typer.Argument(help="Recording (MCAP) with LiDAR clouds and the poses on /tf.")
    ],
    out: Annotated[
        Path, typer.Option(help="Map to write: PCD, with a .json sidecar and the .yaml + .pgm occupancy map.")
    ],
    voxel: Annotated[float, typer.Option(help="Voxel size of the map, m.")] = 0.2,
) -> None:
    """Build a point-cloud map (and its occupancy map) for scan_matching / amcl from a recorded run."""
    from lastmile.core.output_dir import prepare_output_file
    from lastmile.localization.map_build import MapBuildConfig
    from lastmile.runner.map_build_replay import build_map

    try:
        config = MapBuildConfig(voxel_m=voxel)
        prepare_output_file(out, "--out")
        result = build_map(recording, out, config)
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile map build: {exc}", err=True)
        raise typer.Exit(1) from None
    info = result.info
    typer.echo(
        f"wrote {out}: {info.points} points, voxel {info.voxel_m} m, {info.frames_used} of "
        f"{info.frames_total} rig frames ({info.frames_registered} registered, "
        f"{result.frames_skipped_pose} without a usable pose), registration RMSE p50 "
        f"{info.registration_rmse_p50_m} m, correction max {info.correction_max_m} m; occupancy map "
        f"{out.with_suffix('.yaml')}"
    )


calibrate_app = typer.Typer(
    no_args_is_help=True, rich_markup_mode=PLAIN_HELP, help="Calibrate sensors from recorded data."
)
app.add_typer(calibrate_app, name="calibrate")


@calibrate_app.command("lidar")
def calibrate_lidar(
    recording: Annotated[Path, typer.Argument(help="Black-box MCAP with LiDAR clouds and /tf.")],
    reference: Annotated[str, typer.Option(help="LiDAR whose recorded mount is trusted.")] = "lidar_front",
    method: Annotated[
        str, typer.Option(help="planes (Snow Lion's wall corner) or icp (small_gicp point-to-plane).")
    ] = "planes",
    frames: Annotated[int, typer.Option(help="Sweep pairs to calibrate on (least motion first).")] = 3,
    out: Annotated[Path | None, typer.Option(help="Write the mounts as [[lidar_mount]] TOML here.")] = None,
) -> None:
    """Calibrate each other LiDAR's mount against a reference LiDAR; print before/after; write TOML."""
    from rich.console import Console
    from rich.table import Table

    from lastmile.core.output_dir import prepare_output_file
    from lastmile.runner import lidar_calibration_replay as lc

    try:
        methods = {m.value: m for m in lc.Method}
        if method not in methods:
            raise ConfigError(f"--method: expected one of {', '.join(methods)}, got {method!r}")
        if out is not None:
            prepare_output_file(out, "--out")
        results, ref_mount = lc.calibrate_recording(recording, reference, methods[method], frames)
        wrote = out is not None and lc.write_mounts(out, reference, ref_mount, results)
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile calibrate lidar: {exc}", err=True)
        raise typer.Exit(2) from None
    table = Table(title=f"{recording.name}: LiDAR mounts against {reference} ({method})")
    for col in lc.TABLE_COLUMNS:
        table.add_column(col)
    for row in lc.table_rows(results):
        table.add_row(*row)
    Console(width=200).print(table)
    if wrote:
        typer.echo(f"wrote {out}")
    elif out is not None:
        typer.echo(f"no LiDAR calibrated: {out} not written", err=True)
    if any(r.calibrated is None for r in results):
        raise typer.Exit(1)


@calibrate_app.command("camera")
def calibrate_camera(
    folder: Annotated[
        Path, typer.Argument(help="Folder of image + cloud pairs (same stem: PNG/JPG + PCD/.bin).")
    ],
    intrinsics: Annotated[
        Path,
        typer.Option(help="fx fy cx cy width height [k1 k2 p1 p2 k3] TOML/YAML, or ROS camera_info YAML."),
    ],
    board: Annotated[str, typer.Option(help="Inner corners COLSxROWS, e.g. 7x5.")],
    square: Annotated[float, typer.Option(help="Side of a square, m.")],
    nominal: Annotated[
        str,
        typer.Option(
            help="Camera in the LiDAR frame: x,y,z,roll,pitch,yaw (m, deg; body x along the optical axis)."
        ),
    ],
    lidar_mount: Annotated[str, typer.Option(help="LiDAR in the base frame: x,y,z,roll,pitch,yaw (m, deg).")],
    camera_id: Annotated[str, typer.Option(help="The camera's id in the mounts file.")] = "front",
    out: Annotated[
        Path | None, typer.Option(help="Write the mount as [[camera_mount]] TOML (other cameras' rows kept).")
    ] = None,
) -> None:
    """Calibrate a camera's mount against a LiDAR on a checkerboard (Zhang & Pless); print before/after;
    write TOML."""
    from rich.console import Console
    from rich.table import Table

    from lastmile.core.output_dir import prepare_output_file
    from lastmile.localization.camera_mount_file import merge_camera_mounts, read_rows
    from lastmile.runner import camera_calibration_files as cc

    try:
        checkerboard = cc.parse_board(board, square)
        nominal_pose = cc.parse_mount(nominal, "--nominal")
        lidar_pose = cc.parse_mount(lidar_mount, "--lidar-mount")
        if out is not None and prepare_output_file(out, "--out").exists():
            read_rows(out)  # an existing file's other cameras are kept: a bad one is refused before the work
        cal = cc.calibrate_folder(folder, cc.read_intrinsics(intrinsics), checkerboard, nominal_pose)
        mount = cc.mount_row(camera_id, cal, lidar_pose)
        if out is not None:
            merge_camera_mounts(out, mount)
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile calibrate camera: {exc}", err=True)
        raise typer.Exit(2) from None
    table = Table(title=f"{folder.name}: camera {camera_id} against the LiDAR ({len(cal.views)} views)")
    for col in cc.VIEW_COLUMNS:
        table.add_column(col)
    for row in cc.view_rows(cal):
        table.add_row(*row)
    Console(width=200).print(table)
    for line in cc.summary_lines(cal, mount):
        typer.echo(line)
    if out is not None:
        typer.echo(f"wrote {out}")


def _map_recording(path: Path | None, run_config: RunConfig) -> tuple[LoopCallback, ...]:
    """``run --record-map``: the mapping drive's recorder (raw LiDAR perception only)."""
    if path is None:
        return ()
    from lastmile.core.output_dir import prepare_output_file
    from lastmile.runner.map_recording import LidarMapRecording

    if not run_config.stack.perception.needs_raw_sensors:
        raise ConfigError(
            f"--record-map: expected raw LiDAR perception, got '{run_config.stack.perception}' (no sweeps)"
        )
    out = prepare_output_file(path, "--record-map")
    return (LidarMapRecording(out, min_travel_m=2.0, stack=run_config.stack),)


@app.command()
def warmup() -> None:
    """Compile the perception and simulator kernels into the user's cache, once per install: the first
    frame is fast."""
    from lastmile.perception.warmup import main as warm
    from lastmile.sim.lidar_warmup import main as warm_sim

    code = max(warm(), warm_sim())
    if code:
        raise typer.Exit(code)


def main() -> None:
    """The ``lastmile`` entry point: Click's own usage errors (a wrong type, an unknown option) come out
    as one line and exit 2, as the commands' errors do, instead of a usage box."""
    import sys

    # Click's exceptions, from wherever this Typer takes Click (newer Typers vendor it).
    click_exceptions = sys.modules[typer.BadParameter.__module__]
    try:
        code = app(standalone_mode=False)
    except click_exceptions.UsageError as exc:
        command = exc.ctx.command_path if exc.ctx is not None else "lastmile"
        typer.echo(f"{command}: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:  # Ctrl-C outside a run (in a prompt, while importing)
        typer.echo("lastmile: interrupted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # `python -m lastmile.cli ...` works as `lastmile ...` and `python -m lastmile`
    main()
