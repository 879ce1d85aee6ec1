"""``piezopress compare``."""

from __future__ import annotations

import time
from pathlib import Path

import click

from piezopress.piezocli.main import cli, emit_json, json_option, next_command, press_options, reports_errors
from piezopress.pipelines import compare as cmp


@cli.command("compare")
@click.argument("bundles", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="New directory: the runs of every play, compare.csv, repeats.csv, compare.json.",
)
@press_options("plays the bundles")
@click.option(
    "--repeats",
    type=click.IntRange(1, cmp.MAX_REPEATS),
    default=3,
    show_default=True,
    help="Times every plan is played with every bundle (the spread the verdicts are judged against; 1: no verdict).",
)
@click.option(
    "--plan",
    "plans",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Reference plan (repeatable; default: protocols/validate.toml and protocols/tracking.toml).",
)
@click.option(
    "--label",
    "labels",
    multiple=True,
    help="A name for each bundle, in order (repeatable; default: the files' names).",
)
@json_option
@reports_errors
def compare_cmd(bundles, out_dir, rig_path, backend_name, repeats, plans, labels, as_json) -> None:
    """Play the same references with two or more bundles on one press and say which is better.

    Every reference of the plans is compensated with every bundle and checked against the
    press's limits before anything is played. Each repeat plays each plan with every bundle
    in turn, the order reversed on every other repeat (A B, B A, ...), so a drift or a
    warm-up falls on all alike. Per row of Table 6.13 and the tracking rows: each bundle's
    mean and spread over the repeats, and for each bundle after the first its change and a
    verdict: better or worse when every repeat of one beats every repeat of the other,
    Welch's t-test gives p < 0.05 with Holm's correction over the rows and the change is at
    least 5 %, else no difference beyond the spread.

    \b
    Examples:
      piezopress compare build/bundle.json runs/diagnosis/extended_bundle.json --out runs/compare
      piezopress compare base.json ext.json --rig my-press.toml --repeats 5 --label base --label extended --out cmp
    """
    say = (lambda text: click.echo(text, err=True)) if as_json else click.echo
    started = {"t": time.monotonic()}

    def on_play(p: cmp.Play) -> None:
        if not p.done:
            started["t"] = time.monotonic()
            return
        say(
            f"[{p.index:>{len(str(p.total))}}/{p.total}] repeat {p.repeat}, {p.plan}, {p.label}: played "
            f"({time.monotonic() - started['t']:.1f} s) -> {p.out_dir}"
        )

    def warn(text: str) -> None:
        click.echo(f"  warning: {text}", err=True)

    result = cmp.compare(
        bundles,
        out_dir,
        rig_path=rig_path,
        backend_name=backend_name,
        repeats=repeats,
        plans=plans or None,
        labels=labels or None,
        on_play=on_play,
        on_warning=warn,
    )
    files = {
        "compare": result.out_dir / cmp.COMPARE_CSV,
        "repeats": result.out_dir / cmp.REPEATS_CSV,
        "document": result.out_dir / cmp.COMPARE_JSON,
    }
    if as_json:
        emit_json(
            {
                "out_dir": result.out_dir,
                "labels": result.labels,
                "repeats": result.repeats,
                "files": files,
                "warnings": result.warnings,
                "rows": result.table.to_dict(orient="records"),
            }
        )
        return
    say(f"\nCompared on the press, {result.repeats} repeat(s) each (mean ± standard deviation over the repeats):\n")
    say(cmp.format_table(result.table, result.labels))
    if result.repeats < 2:
        say("\nOne repeat: no spread to judge a difference against; use --repeats 3 or more for verdicts.")
    say(f"\nWrote {', '.join(str(f) for f in files.values())}")
    next_command(f"piezopress report --comparison {result.out_dir} --out {result.out_dir}/report")
