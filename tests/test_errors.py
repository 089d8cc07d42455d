"""Error types: did-you-mean suggestions, the RecipeError listing, RolloutDiverged's record, located messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from gns_framework.errors import (
    CheckpointError,
    DatasetError,
    GnsError,
    PluginError,
    PluginWarning,
    RecipeError,
    RolloutDiverged,
    did_you_mean,
    located,
)


def test_did_you_mean_suggests_the_closest_choice():
    assert (
        did_you_mean("interaction_netwrok", ["mlp", "interaction_network"]) == " (did you mean 'interaction_network'?)"
    )
    # A generator of choices works as well as a list (it is read once).
    assert did_you_mean("sand", (c for c in ["water", "sandy"])) == " (did you mean 'sandy'?)"


def test_did_you_mean_says_nothing_without_a_close_choice():
    assert did_you_mean("viscosity", ["friction", "density"]) == ""
    assert did_you_mean("anything", []) == ""


def test_a_recipe_error_lists_every_problem_under_its_source():
    error = RecipeError(Path("runs/recipe.yaml"), [("model.latent_size", "expected an int"), ("", "empty file")])
    assert str(error) == "runs/recipe.yaml: 2 problem(s)\n  model.latent_size: expected an int\n  empty file"
    assert error.source == "runs/recipe.yaml" and error.problems[0] == ("model.latent_size", "expected an int")


def test_a_recipe_error_without_a_source_says_recipe():
    error = RecipeError(None, [("training.steps", "must be > 0")])
    assert error.source == "<recipe>" and str(error).splitlines()[0] == "<recipe>: 1 problem(s)"


def test_a_diverged_rollout_records_where_and_why():
    error = RolloutDiverged("left the domain", trajectory="test_003", step=12, particles=range(2), cause="NaN")
    assert str(error) == "left the domain"
    assert (error.trajectory, error.step, error.particles, error.cause) == ("test_003", 12, [0, 1], "NaN")
    bare = RolloutDiverged("diverged")
    assert (bare.trajectory, bare.step, bare.particles, bare.cause) == ("", -1, [], "")


def test_located_names_the_file_and_the_field_when_there_is_one():
    assert located(Path("data/metadata.json"), "dt", "must be > 0") == "data/metadata.json: dt: must be > 0"
    assert located("data/train.npz", None, "truncated") == "data/train.npz: truncated"
    assert located("data/train.npz", "", "truncated") == "data/train.npz: truncated"


@pytest.mark.parametrize("kind", [PluginError, RecipeError, DatasetError, CheckpointError, RolloutDiverged])
def test_every_error_raised_on_purpose_is_a_gns_error(kind):
    # The command line turns a GnsError into one line of text; anything else is a bug with a traceback.
    assert issubclass(kind, GnsError)


def test_a_plugin_warning_is_a_user_warning_not_an_error():
    assert issubclass(PluginWarning, UserWarning) and not issubclass(PluginWarning, GnsError)
