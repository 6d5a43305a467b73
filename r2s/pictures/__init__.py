"""Annotated pictures people read without the code: text labels, arrows, outlines, colour bars
(:mod:`annotate`), and the judge's rollout picture (:mod:`rollout_picture`)."""
