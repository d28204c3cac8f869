"""QD containers: MAP-Elites grid, CVT archive, unstructured archive, passive archive; the
search archives of novelty search (proximity), DNS, density descent and discount models, and
the pair of a search archive and its result archive.

All are pytrees with `add(genotypes, descriptors, fitnesses) -> (repertoire,
AddResult)` and `sample(key, n) -> genotypes` (the `qdrl.qd.base.Repertoire`
contract); empty cells have fitness -inf.
"""

from qdrl.qd.repertoires.cells import CellRepertoire, cvt_repertoire, grid_repertoire
from qdrl.qd.repertoires.cvt import cvt_centroids
from qdrl.qd.repertoires.density import DensityArchive, density_archive
from qdrl.qd.repertoires.discount import DiscountArchive, discount_archive
from qdrl.qd.repertoires.dns import DNSPopulation, dns_population
from qdrl.qd.repertoires.export import descriptor_columns, export_npz, to_table, write_csv
from qdrl.qd.repertoires.passive import observe, passive_archive
from qdrl.qd.repertoires.proximity import ProximityArchive, proximity_archive
from qdrl.qd.repertoires.result import ResultArchived, with_result_archive
from qdrl.qd.repertoires.unstructured import UnstructuredRepertoire, unstructured_repertoire

__all__ = [
    "CellRepertoire",
    "DNSPopulation",
    "DensityArchive",
    "DiscountArchive",
    "ProximityArchive",
    "ResultArchived",
    "UnstructuredRepertoire",
    "cvt_centroids",
    "cvt_repertoire",
    "density_archive",
    "descriptor_columns",
    "discount_archive",
    "dns_population",
    "export_npz",
    "grid_repertoire",
    "observe",
    "passive_archive",
    "proximity_archive",
    "to_table",
    "unstructured_repertoire",
    "with_result_archive",
    "write_csv",
]
