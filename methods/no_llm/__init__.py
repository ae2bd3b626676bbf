"""Table I row "Ours w/o LLM": no parser; the top visual tokens and an MLP's relations."""

from ocplace.methods.no_llm.recipe import PRESETS as PRESETS  # its entry at each experiment's scale: PRESETS[name]
from ocplace.methods.no_llm.recipe import NoLlmRecipe

TABLE_ROW = 6
RECIPE = NoLlmRecipe  # the type of its entry in `Experiment.recipes`
