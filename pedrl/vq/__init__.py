"""Vector quantisation: k-means (Generalized Lloyd) and the state quantisers of VQQL, IT-VQQL and IN-VQQL.

The k-means function is `pedrl.vq.kmeans.kmeans`; it is not re-exported here, so that `pedrl.vq.kmeans` stays
the module.
"""

from pedrl.vq.kmeans import KMeansResult, PrototypeIndex, nearest_prototype
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer

__all__ = ["KMeansResult", "ProcessQuantizers", "PrototypeIndex", "Quantizer", "UnionQuantizer", "nearest_prototype"]
