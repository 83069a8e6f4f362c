"""New trolley dilemmas from a grammar of the built-in scenarios' building blocks, with exact scores.

The modules, lowest layer first (``tests/test_layers.py``):

* :mod:`~morality_gym.generator.draws`, :mod:`~morality_gym.generator.grammar`,
  :mod:`~morality_gym.generator.writer`, :mod:`~morality_gym.generator.measure` (world layer): the
  choices a seed makes, the plan of a dilemma they give, the scenario file it is written as (the
  ordinary format: a generated file is one a user could have written), and its state graph's size
  and exact harm bounds;
* :mod:`~morality_gym.generator.scoring`, :mod:`~morality_gym.generator.pipeline`,
  :mod:`~morality_gym.generator.splits` (evaluation layer): the oracle and exact Random values that
  decide whether a drawn dilemma is kept, the loop that writes the kept ones with their pictures
  and values, and the fixed train/test splits with their digests.

``docs/how-to/generate-dilemmas.md`` explains the grammar, its limits and the splits.
"""
