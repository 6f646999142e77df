"""The stages of the data flow, one module each in hloc's shape (its configuration, a ``main(conf, inputs, out) ->
Path`` and its ``add_cli(subparsers)``), and the commands that run them. The stages, their artefacts and when each is
reused: see docs/explanation/architecture.md.
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
