"""``forest gallery``: every preset as one tree and as a stand, plus a contact sheet."""

from __future__ import annotations

from pathlib import Path

import click

from cli.app import input_errors, main, needs
from cli.progress import quiet_option, show_progress
from forest.errors import ForestError


@main.command()
@click.option(
    "-o", "--output", type=click.Path(path_type=Path), required=True, help="Folder for the PNGs."
)
@click.option(
    "--presets",
    "presets_text",
    help="Comma-separated preset names (default: every one, see `forest presets`).",
)
@click.option(
    "--size",
    "size_text",
    default="480x640",
    show_default=True,
    help="WIDTHxHEIGHT of a single-tree image; a stand is drawn at HEIGHTxWIDTH.",
)
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--stand-trees", type=int, default=16, show_default=True, help="Trees in each stand.")
@click.option(
    "--recipes",
    "recipes_text",
    help="Comma-separated built-in recipes (`forest recipes`) to draw as a mixed forest, from "
    "above and at eye level; 'all' or 'none'. Default: all for the whole gallery, none when "
    "--presets picks some (a recipe's stand takes minutes on a CPU).",
)
@click.option(
    "--recipe-trees",
    type=int,
    default=200,
    show_default=True,
    help="Trees in each recipe's stand (on 110 m x 110 m).",
)
@quiet_option
@input_errors
def gallery(
    output: Path,
    presets_text: str | None,
    size_text: str,
    seed: int,
    stand_trees: int,
    recipes_text: str | None = None,
    recipe_trees: int = 200,
    quiet: bool = False,
) -> None:
    """Render every preset as one tree (side view on the ground, with a scale bar and its
    height) and as a small stand (overview), into DIR/<preset>.png, DIR/<preset>_stand.png
    and DIR/contact_sheet.png; and every built-in recipe as a mixed forest on its terrain
    (DIR/recipe_<name>.png from above, DIR/recipe_<name>_eye.png at eye level)."""
    needs("render", "moderngl", "PIL")
    from cli.sheets.gallery import GalleryOptions, make_gallery, parse_size

    presets = None
    if presets_text is not None:
        presets = tuple(p.strip() for p in presets_text.split(",") if p.strip())
        if not presets:
            raise ForestError("name at least one preset", path="presets")
    from forest.stand.recipes import recipe_names

    if recipes_text is None:
        recipes_text = "all" if presets is None else "none"
    recipes = tuple(r.strip() for r in recipes_text.split(",") if r.strip())
    if recipes == ("all",):
        recipes = tuple(recipe_names())
    elif recipes in ((), ("none",)):
        recipes = ()
    options = GalleryOptions(
        output=output,
        presets=presets,
        size=parse_size(size_text),
        seed=seed,
        stand_trees=stand_trees,
        recipes=recipes,
        recipe_trees=recipe_trees,
    )
    with show_progress("gallery", quiet) as bar:
        make_gallery(options, echo=bar.echo, progress=bar)
