"""Layer 1, configuration: the error hierarchy, key paths, the strict TOML reader and the validators.

Everything a user's input passes through before it becomes a typed value: ``errors`` (one-line
messages naming the file, the key, what was expected and what was found), ``keypath``
(``loops.cart.controller.gains[1]``), ``validate`` (raw TOML data -> typed values), ``tomlfile``
(the one reader and writer of input files) and ``resources`` (where the shipped models and
scenarios are). May import: the standard library only (no other layer).
"""
