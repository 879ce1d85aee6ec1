"""``piezopress characterize``, ``protocols`` and ``rig-keys``."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from piezopress.piezocli.main import cli, next_command, progress_line, reports_errors
from piezopress.pipelines import characterize as char
from piezopress.pipelines import summary


def _duration(seconds: float) -> str:
    """``42 s``, ``6 min 41 s`` or ``2 h 05 min``."""
    s = int(round(seconds))
    if s < 60:
        return f"{seconds:.3g} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def _print_progress(ev: char.ProgressEvent) -> None:
    """One line per protocol; on a terminal, a bar while the backend reports progress."""
    p = ev.protocol
    width = len(str(ev.total))
    tty = sys.stdout.isatty()
    head = (
        f"[{ev.index:>{width}}/{ev.total}] {p.name:<28} {p.kind:<9} {p.duration_s:8.2f} s "
        f"at {p.sample_rate_hz:g} Hz ... "
    )
    if ev.index == 1 and not ev.done and ev.fraction is None:
        from datetime import datetime, timedelta

        end = (datetime.now() + timedelta(seconds=ev.plan_s)).strftime("%H:%M")
        click.echo(
            f"{ev.total} protocols, {_duration(ev.plan_s)} of drive in all (on a press in real time: done at about "
            f"{end}; "
            f"the virtual rig simulates faster)"
        )
    if ev.fraction is not None:
        if tty:  # redraw the line with a bar
            n = int(round(20 * min(max(ev.fraction, 0.0), 1.0)))
            click.echo(f"\r{head}[{'#' * n}{'.' * (20 - n)}] {100 * ev.fraction:3.0f} %", nl=False)
        return
    if not ev.done:
        click.echo(head, nl=False)
        progress_line(True)
    else:
        if tty:
            click.echo(f"\r{head}", nl=False)
        left = f", {_duration(ev.remaining_s)} of drive left" if ev.remaining_s > 1e-6 else ""
        click.echo(f"done in {ev.elapsed_s:.2f} s{left}")
        progress_line(False)


@cli.command("characterize")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="New directory for the runs (must not exist or be empty).",
)
@click.option(
    "--plan",
    "plan_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=char.DEFAULT_PLAN,
    show_default="protocols/characterize.toml",
    help="Protocol plan (TOML).",
)
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=char.DEFAULT_RIG,
    show_default="rigs/thesis-press.toml",
    help="Rig configuration (TOML).",
)
@click.option(
    "--backend",
    "backend_name",
    default=None,
    help="Which rig runs the plan: a registered name or module:ClassName (default: the rig file's [rig] backend).",
)
@reports_errors
def characterize_cmd(out_dir: Path, plan_path: Path, rig_path: Path, backend_name: str) -> None:
    """Run the scripted characterization protocols and save each run as Parquet.

    The plan is checked completely against the rig's limits before anything runs. The
    output directory gets one run per protocol and a manifest.json (files, sha256, plan,
    rig, software version); existing data is never overwritten. Ctrl-C stops cleanly: the
    drive returns to zero and the manifest records the interruption.

    \b
    Example:
      piezopress characterize --out runs/press-2026-11-21
      piezopress characterize --plan my-plan.toml --rig rigs/thesis-press.toml --out runs/x
    """
    result = char.characterize(
        out_dir, plan_path=plan_path, rig_path=rig_path, backend_name=backend_name, on_progress=_print_progress
    )
    click.echo(f"\n{len(result.runs)} runs written to {result.out_dir} (manifest: {result.manifest_path.name})\n")
    table = summary.characterization_table(result.out_dir)
    click.echo(summary.format_table(table))
    path = summary.write_table(table, result.out_dir / "characterization.csv")
    click.echo(f"\nTable saved as {path}")
    next_command(f"piezopress fit {out_dir} --out {out_dir.parent / (out_dir.name + '-bundle.json')}")


def _copy_new(sources: list[Path], dest_dir: Path) -> list[Path]:
    """Copy files into ``dest_dir`` (made if missing); an existing file there is refused, before any copy."""
    import shutil

    from piezopress.errors import OutputExistsError

    targets = [dest_dir / src.name for src in sources]
    clash = [t for t in targets if t.exists()]
    if clash:
        raise OutputExistsError(
            f"{', '.join(map(str, clash))}: already exist(s); expected a directory without these files (nothing copied)"
        )
    dest_dir.mkdir(parents=True, exist_ok=True)
    for src, dst in zip(sources, targets):
        shutil.copyfile(src, dst)
    return targets


@cli.command("protocols")
@click.option(
    "--copy",
    "copy_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Write editable copies of the shipped plans into this directory.",
)
@reports_errors
def protocols_cmd(copy_dir: Path | None) -> None:
    """List the protocol kinds a plan may use and the keys of each; with --copy, write
    editable copies of the shipped plans (characterize.toml, validate.toml, ...).

    \b
    Example:
      piezopress protocols
      piezopress protocols --copy my-plans      # then: characterize --plan my-plans/characterize.toml
    """
    from piezopress.acquisition.plan import describe_kinds

    if copy_dir is not None:
        for path in _copy_new(sorted(Path(char.DEFAULT_PLAN).parent.glob("*.toml")), copy_dir):
            click.echo(f"Wrote {path}")
        return
    click.echo(describe_kinds())


@cli.command("rig-keys")
@click.option(
    "--template",
    "template",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write an editable rig file: the shipped one of --backend.",
)
@click.option(
    "--backend",
    "backend_name",
    type=click.Choice(char.BACKENDS),
    default="virtual",
    show_default=True,
    help="With --template: a virtual press (thesis-press.toml), an NI-DAQmx press (nidaq-example.toml), or none: "
    "an actuator-only rig file (drive range, slew, sampling; for compensate --rig with a lab's own controller).",
)
@reports_errors
def rig_keys_cmd(template: Path | None, backend_name: str) -> None:
    """List every key of a rig file with its unit, default and allowed range; with
    --template, write an editable copy of a shipped rig file.

    \b
    Example:
      piezopress rig-keys
      piezopress rig-keys --template my-press.toml --backend nidaq
      piezopress rig-keys --template my-actuator.toml --backend none
    """
    from piezopress.acquisition.rig_config import describe_keys

    if template is not None:
        from piezopress.errors import OutputExistsError

        if template.exists():
            raise OutputExistsError(f"{template}: already exists; expected a new file name for the rig file")
        src = Path(char.DEFAULT_RIG).parent / {
            "virtual": "thesis-press.toml",
            "nidaq": "nidaq-example.toml",
            "none": "actuator-only.toml",
        }.get(backend_name, "thesis-press.toml")
        template.parent.mkdir(parents=True, exist_ok=True)
        template.write_bytes(src.read_bytes())
        then = (
            f"piezopress compensate --bundle BUNDLE --reference REF.csv --rig {template} --out drive.csv"
            if backend_name == "none"
            else f"piezopress check-rig --rig {template}"
        )
        click.echo(f"Wrote {template} (from {src.name}; edit it, then: {then})")
        return
    click.echo(describe_keys())
