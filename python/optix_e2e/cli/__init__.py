"""The ``optix`` command line (click). One module per subcommand."""

import click

from .bench import bench
from .dataset import dataset
from .demo import demo
from .design import design
from .detect import detect
from .isp import isp
from .lens import lens
from .metrics import metrics
from .psf import psf
from .sample import sample
from .scenes import scenes
from .sensor import sensor
from .surrogate import surrogate
from .tolerance import tolerance


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="optix-e2e")
def main():
    """optix: exact ray-traced PSFs for compound lenses.

    LENS arguments take a JSON prescription path (docs/lens-format.md), a Zemax .zmx file
    (docs/zemax.md) or the name of a bundled lens (e.g. cooke-f50).
    """


main.add_command(lens)
main.add_command(psf)
main.add_command(demo)
main.add_command(sample)
main.add_command(dataset)
main.add_command(tolerance)
main.add_command(bench)
main.add_command(sensor)
main.add_command(isp)
main.add_command(surrogate)
main.add_command(metrics)
main.add_command(design)
main.add_command(scenes)
main.add_command(detect)
