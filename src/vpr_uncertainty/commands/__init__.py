"""One module per command of the ``vpr-uncertainty`` CLI, each with ``add_parser(subparsers)``.

A command module sets ``handler(args) -> int`` as the parser default and imports heavy dependencies inside
its handler, so that ``--help`` stays fast.
"""
