"""A straightforward networkx implementation of the centralities, one graph per frame.

The benchmark's baseline and the tests' independent reference; not used for scoring.
networkx is a dev/benchmark dependency (``pip install -e .[dev]``).
"""

from __future__ import annotations

import numpy as np

from bgap.cmetric.centrality import Scene


def centralities_networkx(scene: Scene, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """Same contract as :func:`bgap.cmetric.centrality.centralities`."""
    # Imported here: networkx is a test and benchmark reference only (the dev extra).
    import networkx as nx

    n_frames, n = scene.x.shape
    closeness = np.full((n_frames, n), np.nan)
    degree = np.full((n_frames, n), np.nan)
    seen: set[tuple[int, int]] = set()
    count = np.zeros(n)
    started = np.zeros(n, dtype=bool)
    for f in range(n_frames):
        present = np.flatnonzero(scene.present[f])
        graph = nx.Graph()
        graph.add_nodes_from(present.tolist())
        for a, i in enumerate(present):
            for j in present[a + 1 :]:
                d = float(np.hypot(scene.x[f, i] - scene.x[f, j], scene.y[f, i] - scene.y[f, j]))
                if d < mu:
                    graph.add_edge(int(i), int(j), weight=d)
        for i, c in nx.closeness_centrality(graph, distance="weight").items():
            closeness[f, i] = c
        for i in present:
            new = 0
            for j in graph.neighbors(int(i)):
                if (i, j) not in seen:
                    seen.add((i, j))
                    if started[i] and scene.speed[f, j] <= scene.speed[f, i]:
                        new += 1
            started[i] = True
            count[i] += new
            degree[f, i] = count[i]
    return closeness, degree
