"""The paper's reported numbers, one copy for the report and the benchmarks."""

#: The paper's Table 3 (CD and HD x 1e-3, unit box; chi of the medial structure).
TABLE3 = {
    "bunny": (1.86, 12.56, 1),
    "kitten": (1.58, 19.96, 0),
    "block": (0.95, 21.41, -2),
    "sharp_sphere": (1.67, 19.69, 1),
}

#: The paper's Table 1: mean CD and HD (x 1e-3, unit box) over a dataset, by the bench's category of our copy of it
#: (SRB's scans here are the five of Berger et al. that IGR distributes; the paper's are its first 30-50 models).
DATASET_MEANS = {
    "pointclouds/srb": (2.1010, 15.8574),
}
