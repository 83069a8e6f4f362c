"""Baseline learners for MoralityGym.

Sub-packages and modules each hold one family of learners; :mod:`morality_gym.baselines.safe`
holds the constrained (CMDP) learners PPO-Lagrangian and CPO. Nothing is imported here, so that
``import morality_gym.baselines`` stays cheap and free of torch for users of other baselines.
"""
