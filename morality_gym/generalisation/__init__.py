"""The generalisation track: one policy trained on the generated ``train`` split, scored zero-shot.

* :mod:`~morality_gym.generalisation.mixture`: :class:`DilemmaMixtureEnv`, a Gymnasium env whose
  every episode is a dilemma drawn (by the env's seed) from a pool of env ids, all seen through the
  fixed-shape grid observation, so that one policy acts in every dilemma;
* :mod:`~morality_gym.generalisation.sets`: the three evaluation sets (a fixed sample of the seen
  ``train`` dilemmas, the held-out ``test`` split, the 98 built-in envs), the chain(s) each env id
  is scored under and their exact oracle best/worst and Random values;
* :mod:`~morality_gym.generalisation.scoring`: the exact score of a grid policy on a set.

``runners/track.py`` trains and evaluates; ``leaderboard/track.py`` shows the results;
``docs/how-to/generalisation-track.md`` explains the track.
"""
