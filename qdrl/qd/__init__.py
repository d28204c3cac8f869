"""Quality-Diversity: repertoires, emitters and the one QD loop (`map_elites`)."""
