"""The stages of the data flow, one module each in hloc's shape, and the commands that run them.

Each stage module holds its configuration (a frozen dataclass whose fields are also its command-line options), a
``main(conf, inputs, out) -> Path`` and its ``add_cli(subparsers)``:

=====================  ==========================  ===================================================================
module                 artefact                    reused when
=====================  ==========================  ===================================================================
:mod:`.extract`        ``descriptors.h5``          per image: same model, preprocessing and image content
:mod:`.retrieve`       ``retrieval.npz``           same options, descriptors and ground truth
:mod:`.evaluate`       ``uncertainties.npz``       never (it measures the time per query)
:mod:`.verify`         ``verification.npz``        never; each image's local features are cached
:mod:`.report`         ``results.{json,md}``, plot never (cheap)
:mod:`.run`            all of the above            the one composer (``run``, ``demo``)
:mod:`.grid`           ``out/cells``, report.html  per cell: same inputs (by content) and settings (``reproduce``)
=====================  ==========================  ===================================================================

:mod:`.compare`, :mod:`.calibrate`, :mod:`.label`, :mod:`.subset`, :mod:`.datasets`, :mod:`.train_btl`: commands beside
the data flow.
"""

#: Each command and the stage module whose ``add_cli`` defines it, in the order ``--help`` lists them. The command
#: line imports only the module of the command it runs (``tests/test_cli.py`` checks this table against the
#: commands the modules define).
COMMANDS: dict[str, str] = {
    "demo": "run",
    "run": "run",
    "evaluate": "evaluate",
    "compare": "compare",
    "calibrate": "calibrate",
    "label": "label",
    "subset": "subset",
    "reproduce": "grid",
    "datasets": "datasets",
    "extract": "extract",
    "retrieve": "retrieve",
    "verify": "verify",
    "train-btl": "train_btl",
    "loop-closures": "loop_closures",
}

#: The modules whose ``add_cli`` the command line collects, in the order ``--help`` lists their commands.
COMMAND_MODULES: tuple[str, ...] = tuple(dict.fromkeys(COMMANDS.values()))
