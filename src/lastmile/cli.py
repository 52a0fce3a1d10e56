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
    from lastmile.runner.run_config import RunConfig

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="Autonomous campus shuttle: stack, simulator, tools."
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
) -> None:
    """Simulate the shuttle service in closed loop and write a run directory with report.md."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    if fleet is not None or serve:
        _run_fleet(fleet, serve, minutes, seed, demand, out, scenario is not None or weather is not None)
        return

    try:
        from lastmile.runner.closed_loop import evaluate_run, load_world_map, run_scenario
        from lastmile.sim.scenario import MapSpec, default_service, load_scenario, route_service
        from lastmile.sim.weather import parse_weather

        run_config = _run_config(config, perception, PERCEPTION_OPTIONS["lidar"])
        if not black_box:
            run_config = dataclasses.replace(
                run_config, loop=dataclasses.replace(run_config.loop, black_box=False)
            )
        if scenario is not None:
            spec = load_scenario(scenario)
            if route is not None:
                spec = dataclasses.replace(spec, map=MapSpec(name="route", route=str(route)))
        else:
            spec = route_service(str(route)) if route is not None else default_service()
        overrides: dict[str, object] = {}
        if minutes is not None:
            overrides["minutes"] = minutes
        if seed is not None:
            overrides["seed"] = seed
        if weather is not None:
            parse_weather(weather)
            overrides["weather"] = weather
        spec = dataclasses.replace(spec, **overrides)  # type: ignore[arg-type]
        run_config.check_serves(spec)
        with Progress(
            TextColumn("[bold]simulating[/bold] {task.description}"),
            BarColumn(),
            TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
            TimeElapsedColumn(),
        ) as bar:
            task = bar.add_task(f"{spec.name} seed {spec.seed} {spec.weather}", total=spec.minutes * 60.0)
            log = run_scenario(
                spec,
                run_config,
                progress=lambda done, total: bar.update(task, completed=done),
                black_box_dir=out / "recordings",
            )
        metrics = evaluate_run(log, out, hdmap=load_world_map(spec.map).hdmap)
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    if log.timing.get("interrupted"):
        typer.echo(
            f"lastmile run: interrupted; wrote the {metrics['duration_s']:.0f} s simulated so far to {out}",
            err=True,
        )
        raise typer.Exit(130)
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
) -> None:
    """``lastmile run --fleet N --serve``: see :mod:`lastmile.runner.fleet_run`."""
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
        from lastmile.runner.fleet_config import FleetConfig
        from lastmile.runner.fleet_run import run_fleet

        config = FleetConfig(
            shuttles=fleet,
            minutes=minutes if minutes is not None else 10.0,
            seed=seed if seed is not None else 0,
            demand_per_pair_per_h=demand,
        )
        with Progress(
            TextColumn(f"[bold]simulating[/bold] {fleet} shuttles with the server"),
            BarColumn(),
            TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
            TimeElapsedColumn(),
        ) as bar:
            task = bar.add_task("fleet", total=config.minutes * 60.0)
            m = run_fleet(config, out, progress=lambda done, total: bar.update(task, completed=done))
    except LastmileError as exc:
        typer.echo(f"lastmile run: {exc}", err=True)
        raise typer.Exit(2) from None
    wait = m["wait_s"]["median"]
    typer.echo(
        f"wrote {out}/fleet_report.md: {m['requests_served']}/{m['requests_made']} requests served, "
        f"median wait {'-' if wait is None else f'{wait:.0f} s'}, "
        f"{m['fleet_distance_km']:.1f} km, real-time factor {m['timing']['realtime_factor']:.1f}x"
    )


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
) -> None:
    """Run many scenarios; writes summary.json, report.md and every scenario file under OUT."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    try:
        from lastmile.evaluation.sweep_report import write_sweep_report
        from lastmile.runner.sweep import generic_cases, run_sweep
        from lastmile.sim.scenario import load_scenario
        from lastmile.sim.scenario_generator import ScenarioSpace, sample_scenarios
        from lastmile.sim.suites import SUITES

        run_config = _run_config(config, perception, PERCEPTION_OPTIONS["radar"])
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
            cases = generic_cases(sample_scenarios(ScenarioSpace(), generate, seed))
            title = f"Sweep: {generate} generated scenarios (seed {seed})"
        else:
            assert scenarios is not None
            files = sorted(scenarios.glob("*.toml"))
            if not files:
                raise ConfigError(f"sweep --scenarios: expected TOML files in {scenarios}, got none")
            cases = generic_cases([load_scenario(f) for f in files], group=str(scenarios))
            title = f"Sweep: {len(files)} scenarios from {scenarios}"
        with Progress(
            TextColumn("[bold]sweep[/bold]"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
        ) as bar:
            task = bar.add_task("scenarios", total=len(cases))
            summary = run_sweep(
                cases,
                out,
                engine=engine,
                workers=workers,
                ray_address=ray_address,
                progress=lambda done, total: bar.update(task, completed=done),
                config=run_config,
            )
        report = write_sweep_report(summary, out, title)
    except LastmileError as exc:
        typer.echo(f"lastmile sweep: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(
        f"wrote {report}: {summary['passed']}/{summary['scenarios']} passed, "
        f"{summary['collisions_at_fault']} at-fault collisions"
    )


experiment_app = typer.Typer(no_args_is_help=True, help="Reproduce the papers' experiments.")
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
) -> None:
    """Run the dispatch server (HTTP + WebSocket API, web dashboard) until interrupted."""
    from lastmile.fleet.serve_main import serve as serve_forever

    try:
        serve_forever(
            host=host,
            port=port,
            db=db,
            out=out,
            runs=runs,
            timetable_lead_s=timetable_lead,
            announce=typer.echo,
        )
    except LastmileError as exc:
        typer.echo(f"lastmile serve: {exc}", err=True)
        raise typer.Exit(2) from None


map_app = typer.Typer(no_args_is_help=True, help="Check maps and route files for a shuttle service.")
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
) -> None:
    """Run the LiDAR pipeline on point-cloud files: KITTI object labels, a Foxglove MCAP, timing."""
    from lastmile.perception.perceive import load_perceive_config, perceive_files, summary_lines

    try:
        frames = perceive_files(files, load_perceive_config(config), out)
    except (LastmileError, OSError) as exc:
        typer.echo(f"lastmile perceive: {exc}", err=True)
        raise typer.Exit(2) from None
    for line in summary_lines(frames):
        typer.echo(line)
    typer.echo(f"wrote {out / 'labels'}/, {out / 'objects.mcap'} and {out / 'timing.json'}")


def main() -> None:
    app()


if __name__ == "__main__":  # `python -m lastmile.cli ...` as the README and the briefs run it
    main()
