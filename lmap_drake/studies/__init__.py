"""Studies: evaluation-level code behind the ``scripts/`` that measure the
method against the ground truth of the simulated plant world (the hazard
study, deformation vs FEM, the shape table, the action oracle, the held
leaf, the energy-cap calibration, segmentation and fruit detection), the
segmentation network's training renders and its fine-tuning on a lab's
annotated captures (``lmap-drake train-segmenter``), and the benchmarks (process pool
against Ray, the deformation predictor, the planner's stages, the
station's realtime factor, the digital twin's pace, the multi-fruit
scenes rendered and measured, every fruit of a plant planned from its
first view).

A study may import the systems, the diagram and the episode runner;
nothing in the algorithms, systems, diagram or episode may import a study.
Each ``scripts/NAME.py`` is a thin argparse shell around one of these
modules (same flags, outputs and exit codes).
"""
