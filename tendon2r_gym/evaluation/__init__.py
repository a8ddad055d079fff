"""Rollouts of a policy, tracking metrics, evaluation by policy name and PD tuning by
rollouts."""
