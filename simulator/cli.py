"""`spotless-sim`: generate rooms and render paired datasets. Commands stay thin: they build a config and call one
library function."""

from __future__ import annotations

import click


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spotlessgs")
def main() -> None:
    """SpotlessGS simulator: 3D-FRONT-format rooms -> paired uneven / evenly lit datasets."""


if __name__ == "__main__":
    main()
