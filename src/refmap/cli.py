"""Command line: ``refmap list``, ``refmap run SCENARIO``, ``refmap resume DIR``,
``refmap plot DIR``, ``refmap movie DIR``, ``refmap info DIR`` and
``refmap convergence SCENARIO``."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="refmap: Eulerian fluid-structure interaction (blurred-interface reference map technique).")


@app.command("list")
def list_cmd():
    """Show the built-in scenarios."""
    from refmap.scenarios import DESCRIPTIONS, SCENARIOS

    for name in SCENARIOS:
        c = SCENARIOS[name]()
        typer.echo(f"{name:10s} {DESCRIPTIONS[name]}  [default t_end={c.t_end:g}, frames={c.frames}]")


@app.command("show")
def show_cmd(
    scenario: str = typer.Argument(..., help="built-in scenario to print as a case file"),
    n: int = typer.Option(None, "--n", help="grid cells per side"),
    out: Path = typer.Option(None, "--out", help="write here instead of printing"),
):
    """Print a built-in scenario as a TOML case file (`refmap show rotor > rotor.toml`)."""
    from refmap.case import CaseError
    from refmap.casefile import show_scenario

    try:
        text = show_scenario(scenario, n)
    except CaseError as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(2) from None
    if out is None:
        typer.echo(text, nl=False)
    else:
        out.write_text(text, encoding="utf-8")
        typer.echo(f"wrote {out}")


@app.command("run")
def run_cmd(
    scenario: str = typer.Argument(..., help="scenario name (see `refmap list`) or a case file (.toml)"),
    n: int = typer.Option(None, "--n", help="grid cells per side (default 128 in 2D, 32 in 3D, or the case file's)"),
    t_end: float = typer.Option(None, "--t-end", help="end time (default: the scenario's)"),
    frames: int = typer.Option(None, "--frames", help="number of output frames"),
    out: Path = typer.Option(None, "--out", help="run folder (default runs/SCENARIO_N)"),
    cfl: float = typer.Option(None, "--cfl", help="time-step safety factor (default: the scenario's)"),
    movie: bool = typer.Option(None, "--movie/--no-movie", help="also write an MP4 of the picture field"),
    pictures: bool = typer.Option(None, "--pictures/--no-pictures", help="write PNG snapshots"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace the run in an existing run folder "
                                   "(its frames, diagnostics, metadata, checkpoints and summary are "
                                   "deleted; other files are kept)"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    checkpoint_every: int = typer.Option(1, "--checkpoint-every", min=1, help="frames between checkpoints"),
    devices: int = typer.Option(None, "--devices", help="split the grid along x over this many devices "
                                "(nx must be divisible by it; on a CPU, virtual devices)"),
):
    """Run a scenario or a case file, writing HDF5 frames, an XDMF index, diagnostics and pictures.

    An existing, non-empty run folder is refused unless --overwrite is given.  Exit codes:
    0 done, 2 bad input (nothing run), 3 the run blew up, 4 the run could not be written
    (disk full, permissions), 130 interrupted (Ctrl-C)."""
    from refmap.case import CaseError
    from refmap.casefile import is_case_file, load_run
    from refmap.scenarios import get_case
    from refmap.simulation import Simulation, format_rate

    _request_devices(devices)
    try:
        if is_case_file(scenario):
            plan = load_run(scenario, {"n": n, "t_end": t_end, "frames": frames, "cfl": cfl,
                                       "out": out, "movie": movie, "pictures": pictures})
            case, out_dir, movie, pictures = plan.case, plan.out_dir, plan.movie, plan.pictures
        else:
            case = get_case(scenario, n)  # n None: the scenario's default (128 in 2D, 32 in 3D)
            n = case.grid.nx
            if t_end is not None:
                case = case.replace(t_end=t_end)
            if frames is not None:
                case = case.replace(frames=frames)
            if cfl is not None:
                from dataclasses import replace

                case = case.replace(numerics=replace(case.numerics, cfl=cfl))
            out_dir = out if out is not None else Path("runs") / f"{scenario}_{n}"
            movie = bool(movie)
            pictures = True if pictures is None else pictures
        _check_out_dir(Path(out_dir), overwrite)
        case.validate()
        sim = Simulation(case, out_dir, progress=progress, pictures=pictures, movie=movie,
                         overwrite=overwrite, command=" ".join(["refmap"] + sys.argv[1:]),
                         checkpoint_every=checkpoint_every, devices=devices)
    except (CaseError, ValueError, FileExistsError) as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(2) from None
    _run_sim(sim, out_dir)
    typer.echo(
        f"done: {sim.total_steps} steps in {sim.wall_time:.1f} s "
        f"({format_rate(sim.total_steps / max(sim.wall_time, 1e-9))} steps/s); output in {out_dir}"
    )
    if sim.conservation_text():
        typer.echo(sim.conservation_text())


def _request_devices(devices) -> None:
    """Before JAX starts: on a CPU, ask for ``devices`` virtual devices (refmap.sharding)."""
    if devices is not None and devices > 1:
        from refmap.sharding import request_cpu_devices

        request_cpu_devices(devices)


def _check_out_dir(out_dir: Path, overwrite: bool) -> None:
    """Refuse, before anything is computed, an output path that is a file, or a non-empty
    folder without --overwrite."""
    if out_dir.exists() and not out_dir.is_dir():
        raise FileExistsError(f"output path {str(out_dir)!r} exists and is not a folder; "
                              "choose another --out")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not overwrite:
        raise FileExistsError(f"run folder {str(out_dir)!r} is not empty (a previous run?); pass "
                              "--overwrite to replace its run, `refmap resume` to continue it, or "
                              "choose another --out")


def _run_sim(sim, out_dir) -> None:
    """sim.run() with every way it can end turned into a message and an exit code."""
    from refmap.simulation import SimulationBlowUp

    try:
        sim.run()
    except SimulationBlowUp as e:
        _fail(str(e), 3)
    except FileExistsError as e:
        _fail(str(e), 2)
    except OSError as e:
        what = e.strerror or str(e)
        where = f" ({e.filename})" if getattr(e, "filename", None) else ""
        _fail(f"cannot write the run to {out_dir}: {what}{where}; [Errno {e.errno}]; free some space "
              f"or choose another --out (frames written so far are kept)", 4)
    except KeyboardInterrupt:  # Simulation.run has said what it left in the folder
        _fail("interrupted", 130)


# ---------------------------------------------------------------------- restart and post-processing
def _fail(msg: str, code: int = 2):
    typer.secho(f"error: {msg}", fg="red", err=True)
    raise typer.Exit(code)


@app.command("resume")
def resume_cmd(
    run_dir: Path = typer.Argument(..., help="run folder holding checkpoint.h5"),
    t_end: float = typer.Option(None, "--t-end", help="extend the run to this end time"),
    frames: int = typer.Option(None, "--frames", help="with --t-end: frame intervals from 0 to t_end"),
    checkpoint_every: int = typer.Option(1, "--checkpoint-every", help="frames between checkpoints"),
    movie: bool = typer.Option(False, "--movie/--no-movie", help="also write an MP4 of the picture field"),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="write PNG snapshots"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    devices: int = typer.Option(None, "--devices", help="split the grid along x over this many devices"),
):
    """Continue a run from its checkpoint (after Ctrl-C, a crash, or to extend it)."""
    from refmap.case import CaseError
    from refmap.checkpoint import CheckpointError
    from refmap.simulation import Simulation

    if not run_dir.is_dir():
        _fail(f"no run folder '{run_dir}'")
    _request_devices(devices)
    try:
        sim = Simulation.resume(run_dir, t_end=t_end, frames=frames, progress=progress,
                                pictures=pictures, movie=movie, checkpoint_every=checkpoint_every,
                                command=" ".join(["refmap"] + sys.argv[1:]), devices=devices)
    except (CheckpointError, CaseError, ValueError, FileNotFoundError) as e:
        _fail(str(e))
    r = sim._resume_from
    if sim.complete:
        typer.echo(f"run in {run_dir} is already complete at t = {float(r['t']):g}; "
                   "pass --t-end to extend it")
        return
    typer.echo(f"resuming {sim.case.name} from frame {r['frame_index']} (t = {float(r['t']):g}) "
               f"to t = {sim.case.t_end:g}")
    _run_sim(sim, run_dir)
    typer.echo(f"done: {sim.total_steps} steps in {sim.wall_time:.1f} s in all; output in {run_dir}")
    if sim.conservation_text():
        typer.echo(sim.conservation_text())


@app.command("plot")
def plot_cmd(
    run_dir: Path = typer.Argument(..., help="run folder"),
    field: str = typer.Option(..., "--field", help="stored field or vorticity, speed, pressure, von_mises"),
    time: float = typer.Option(..., "--time", help="simulated time (the nearest frame is drawn)"),
    out: Path = typer.Option(None, "--out", help="PNG file (default RUN/plots/FIELD_tTIME.png)"),
    solid: int = typer.Option(None, "--solid", help="which solid, for a per-solid field (J, phi, ...)"),
):
    """PNG of one field at one time, with the interfaces drawn."""
    from refmap.postprocess import PostprocessError, plot_frame

    try:
        path = plot_frame(run_dir, field, time, out=out, solid=solid)
    except PostprocessError as e:
        _fail(str(e))
    typer.echo(f"wrote {path}")


@app.command("movie")
def movie_cmd(
    run_dir: Path = typer.Argument(..., help="run folder"),
    field: str = typer.Option("pressure", "--field", help="stored field or vorticity, speed, pressure, von_mises"),
    out: Path = typer.Option(None, "--out", help="MP4 file (default RUN/FIELD.mp4)"),
    fps: int = typer.Option(15, "--fps", help="frames per second"),
    solid: int = typer.Option(None, "--solid", help="which solid, for a per-solid field"),
):
    """MP4 of one field over the whole run (colour range fixed over time, interfaces drawn)."""
    from refmap.postprocess import PostprocessError, make_run_movie

    try:
        path = make_run_movie(run_dir, field, out=out, fps=fps, solid=solid)
    except PostprocessError as e:
        _fail(str(e))
    typer.echo(f"wrote {path}")


@app.command("info")
def info_cmd(run_dir: Path = typer.Argument(..., help="run folder")):
    """Summary of a run: case, versions, frames and steps, wall time, dt, conservation."""
    from refmap.postprocess import PostprocessError, format_info, run_info

    try:
        typer.echo(format_info(run_info(run_dir)))
    except PostprocessError as e:
        _fail(str(e))


@app.command("convergence")
def convergence_cmd(
    scenario: str = typer.Argument(..., help="built-in scenario whose factory takes the grid size n"),
    grids: str = typer.Option("60,72,90,120,180", "--grids", help="comma-separated grid sizes of the ladder"),
    ref: int = typer.Option(360, "--ref", help="reference grid size, finer than every rung"),
    t_end: float = typer.Option(None, "--t-end", help="common end time (default: the scenario's)"),
    out: Path = typer.Option(None, "--out", help="folder for the rungs and results (default runs/convergence_SCENARIO)"),
    jobs: int = typer.Option(1, "--jobs", min=1, help="rungs run at once, each in its own process"),
    margin: float = typer.Option(1.0, "--margin", min=0.0,
                                 help="compare xi and grad xi only where phi < -margin*h_coarse in every run"),
    viscosity: str = typer.Option(None, "--viscosity",
                                  help="explicit or implicit viscous step for every rung (default: the "
                                       "scenario's; the thesis's rotor study is explicit)"),
    kernel: str = typer.Option(None, "--kernel",
                               help="blend kernel and width in cells for every rung, e.g. sine:1 or "
                                    "erf:2 (default: the scenario's)"),
):
    """Grid-convergence study: run a ladder of grids to a common time (finished rungs are
    reused), compare each with the reference on the coarsest grid's nodes (discrete L2 and
    max norms of u, v, xi and grad xi) and fit observed orders.  Writes SCENARIO_nN.npz per
    rung, convergence.csv and convergence.png into the output folder."""
    from refmap.convergence import ConvergenceError, check_study, format_table, study

    try:
        check_study(scenario, grids, ref, t_end, viscosity, kernel)
    except ConvergenceError as e:
        _fail(str(e))
    out_dir = out if out is not None else Path("runs") / f"convergence_{scenario}"
    try:
        st = study(scenario, grids, ref, t_end, out_dir, jobs=jobs, margin=margin,
                   viscosity=viscosity, kernel=kernel)
    except ConvergenceError as e:
        _fail(str(e), 3)
    typer.echo(format_table(st))
    typer.echo(f"wrote {out_dir / 'convergence.csv'} and {out_dir / 'convergence.png'}")


def main():  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
