"""``piezopress validate``."""

from __future__ import annotations

from pathlib import Path

import click

from piezopress.piezocli.cmd_characterize import _print_progress
from piezopress.piezocli.main import cli, emit_json, json_option, next_command, press_options, reports_errors
from piezopress.pipelines import summary
from piezopress.pipelines import validate as val


@cli.command("validate")
@click.option(
    "--bundle",
    "bundle_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Parameter bundle (from `piezopress fit` or `bundle`).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="New directory for the runs.",
)
@click.option(
    "--plan",
    "plan_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=val.DEFAULT_VALIDATION_PLAN,
    show_default="protocols/validate.toml",
    help="Reference plan (forces in N above the preload).",
)
@press_options("runs the plan")
@click.option("--no-shaper", is_flag=True, help="Run without the input shaper (Table 6.12's comparison).")
@click.option("--no-creep", is_flag=True, help="Run without the creep compensator.")
@json_option
@reports_errors
def validate_cmd(bundle_path, out_dir, plan_path, rig_path, backend_name, no_shaper, no_creep, as_json) -> None:
    """Run the thesis's chapter 6 tests with the compensation applied.

    Every reference of the plan is compensated with the bundle (shaper, creep compensator,
    inverse hysteresis) and played through the backend; runs carry reference_n. Prints the
    validation table with the thesis's figures beside it.

    \b
    Example:
      piezopress validate --bundle build/bundle.json --out runs/validation
    """
    warnings: list[str] = []

    def warn(w: str) -> None:
        warnings.append(w)
        click.echo(f"\n  warning: {w}", err=True)

    result = val.validate(
        out_dir,
        bundle_path,
        plan_path=plan_path,
        rig_path=rig_path,
        backend_name=backend_name,
        use_shaper=not no_shaper,
        use_creep=not no_creep,
        on_progress=None if as_json else _print_progress,
        on_warning=warn,
    )
    table = summary.validation_table(result.out_dir)
    path = summary.write_table(table, result.out_dir / "validation.csv")
    if as_json:
        emit_json(
            {
                "out_dir": result.out_dir,
                "runs": result.runs,
                "table": path,
                "warnings": warnings,
                "rows": table.to_dict(orient="records"),
            }
        )
        return
    click.echo(f"\n{len(result.runs)} runs written to {result.out_dir}\n")
    click.echo(summary.format_table(table, title="Validation (compensated)"))
    click.echo(f"\nTable saved as {path}")
    next_command(
        f"piezopress report --validation {result.out_dir} --bundle {bundle_path} "
        f"--characterization CHARACTERIZATION_DIR --out {result.out_dir.parent / (result.out_dir.name + '-report')}"
    )
