"""QD containers: MAP-Elites grid, CVT archive, unstructured archive, passive archive.

All are pytrees with `add(genotypes, descriptors, fitnesses) -> (repertoire,
AddResult)` and `sample(key, n) -> genotypes` (the `qdrl.qd.base.Repertoire`
contract); empty cells have fitness -inf.
"""

from qdrl.qd.repertoires.cells import CellRepertoire, cvt_repertoire, grid_repertoire
from qdrl.qd.repertoires.cvt import cvt_centroids
from qdrl.qd.repertoires.export import descriptor_columns, export_npz, to_table, write_csv
from qdrl.qd.repertoires.passive import observe, passive_archive
from qdrl.qd.repertoires.unstructured import UnstructuredRepertoire, unstructured_repertoire

__all__ = [
    "CellRepertoire",
    "UnstructuredRepertoire",
    "cvt_centroids",
    "cvt_repertoire",
    "descriptor_columns",
    "export_npz",
    "grid_repertoire",
    "observe",
    "passive_archive",
    "to_table",
    "unstructured_repertoire",
    "write_csv",
]
