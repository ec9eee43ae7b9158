"""Command line: ``refmap list`` and ``refmap run SCENARIO``."""

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


@app.command("run")
def run_cmd(
    scenario: str = typer.Argument(..., help="scenario name (see `refmap list`)"),
    n: int = typer.Option(128, "--n", help="grid cells per side"),
    t_end: float = typer.Option(None, "--t-end", help="end time (default: the scenario's)"),
    frames: int = typer.Option(None, "--frames", help="number of output frames"),
    out: Path = typer.Option(None, "--out", help="run folder (default runs/SCENARIO_N)"),
    cfl: float = typer.Option(None, "--cfl", help="time-step safety factor (default: the scenario's)"),
    movie: bool = typer.Option(False, "--movie/--no-movie", help="also write an MP4 of the picture field"),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="write PNG snapshots"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing run folder"),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
):
    """Run a scenario, writing HDF5 frames, an XDMF index, diagnostics and pictures."""
    from refmap.case import CaseError
    from refmap.scenarios import get_case
    from refmap.simulation import Simulation, SimulationBlowUp

    try:
        case = get_case(scenario, n)
        if t_end is not None:
            case = case.replace(t_end=t_end)
        if frames is not None:
            case = case.replace(frames=frames)
        if cfl is not None:
            from dataclasses import replace

            case = case.replace(numerics=replace(case.numerics, cfl=cfl))
        case.validate()
        out_dir = out if out is not None else Path("runs") / f"{scenario}_{n}"
        sim = Simulation(case, out_dir, progress=progress, pictures=pictures, movie=movie,
                         overwrite=overwrite, command=" ".join(["refmap"] + sys.argv[1:]))
    except (CaseError, ValueError, FileExistsError) as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(2) from None
    try:
        sim.run()
    except SimulationBlowUp as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(3) from None
    typer.echo(
        f"done: {sim.total_steps} steps in {sim.wall_time:.1f} s "
        f"({sim.total_steps / max(sim.wall_time, 1e-9):.0f} steps/s); output in {out_dir}"
    )


def main():  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
