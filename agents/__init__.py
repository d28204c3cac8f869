"""The experiment specs shipped with qdrl, installed as the data package `qdrl._specs`.

`qdrl list` shows them with their first comment line; `qdrl run NAME` runs one by
name (`qdrl.specs.resolve`).
"""
