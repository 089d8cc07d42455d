"""Built-in processors."""

from gns_framework.api import hookimpl

from .egnn import EquivariantProcessor
from .graph_attention import GraphAttentionProcessor
from .grid_cnn import GridProcessor
from .interaction_network import InteractionNetwork
from .shared_interaction_network import SharedInteractionNetwork


@hookimpl
def gns_processors():
    return [InteractionNetwork, SharedInteractionNetwork, GraphAttentionProcessor, EquivariantProcessor, GridProcessor]
