"""Evaluation of semi-active control laws: scenarios, runner, tables, plots, seed reproductions."""
