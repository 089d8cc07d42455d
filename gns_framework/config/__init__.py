"""Recipes and the YAML they are read from: schema, one-pass validation and located problems."""
