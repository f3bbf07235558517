"""Renderers: report.md, figures and command-line text, read from results (never from models)."""
