"""The `digail` subcommands: one module per command, each with its argument dataclass and the function that runs it.

Commands sit on top of the library (`eval`, `viz`, `algos`, ...): they parse nothing themselves (tyro builds the
arguments from the dataclasses), read and write run folders, and print where the results went.
"""
