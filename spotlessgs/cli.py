"""`spotless`: train, relight, render and evaluate. Commands stay thin: they build a config and call one library
function."""

from __future__ import annotations

import click
from evaluation.cli import eval_command


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spotlessgs")
def main() -> None:
    """SpotlessGS: relightable Gaussian Splatting for images lit by an onboard spotlight."""


main.add_command(eval_command, name="eval")
if __name__ == "__main__":
    main()
