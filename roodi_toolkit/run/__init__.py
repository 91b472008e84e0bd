"""The run layer: the folders of a run around the in-memory stages of :mod:`roodi_toolkit.pipeline` and
:mod:`roodi_toolkit.evaluate`.

A stage is a function of in-memory values (a ``Dataset``, a cloud or parameters, a ``Renderer``, a config) that
returns a result value; it opens, names and checks no file. This floor owns everything a run does with files around
them: output folders (an output is never an input, ``--overwrite``, atomic groups: :mod:`roodi_toolkit.io.files`),
stage records (``cfg.json``, ``distill.json``, ``stage.json``, ``report.json``) and the reuse of a finished stage,
resume from a checkpoint (training's), and the pictures a stage's result is shown in. It sits above the stages and the
metrics and below what calls it: the demo (:mod:`roodi_toolkit.synth.demo`), :mod:`roodi_toolkit.batch` and the CLI.
"""
