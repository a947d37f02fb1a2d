"""DeepC confidence network (Kuhn et al. 2020, §3.2): inputs, label maps, the middle-fusion U-Net, losses,
ROC-AUC, weights I/O, tiled inference and training (PyTorch on the CPU)."""

from engine.confidence.inputs import encode_normals, network_inputs
from engine.confidence.labels import UNLABELED, label_map
from engine.confidence.metrics import roc_auc, sparsification

__all__ = ["UNLABELED", "encode_normals", "label_map", "network_inputs", "roc_auc", "sparsification"]
