"""Vector quantisation: k-means (Generalized Lloyd) and the state quantisers of VQQL, IT-VQQL and IN-VQQL.

The k-means function is `pedrl.vq.kmeans.kmeans`; it is not re-exported here, so that `pedrl.vq.kmeans` stays
the module.
"""

from pedrl.vq.factored import FactoredQuantizer, FactorSpec, factor_specs
from pedrl.vq.kmeans import KMeansResult, PrototypeIndex, nearest_prototype
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer

__all__ = [
    "FactorSpec",
    "FactoredQuantizer",
    "KMeansResult",
    "ProcessQuantizers",
    "PrototypeIndex",
    "Quantizer",
    "UnionQuantizer",
    "factor_specs",
    "nearest_prototype",
]
