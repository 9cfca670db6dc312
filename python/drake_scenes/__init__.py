"""drake_scenes: physically stable box scenes with Drake (paper, step 1).

Modules, one concern each: recipe (reading datasets/recipes/*.toml), sampling (random boxes and
drop poses), plant (the support and boxes as a MultibodyPlant), projection (non-penetration
solve), settle (drop, simulate, certify), generate (scenes → contract rows → shards), cli.
"""
