"""One module per pbrlib closure; ``LOBE_CLASSES`` maps a node category to its lobe."""

from .conductor import ConductorLobe
from .dielectric import DielectricLobe
from .diffuse import BurleyLobe, OrenNayarLobe, TranslucentLobe
from .generalized_schlick import GeneralizedSchlickLobe
from .sheen import SheenLobe
from .subsurface import SubsurfaceLobe

LOBE_CLASSES = {cls.category: cls for cls in (
    ConductorLobe, DielectricLobe, BurleyLobe, OrenNayarLobe, TranslucentLobe,
    GeneralizedSchlickLobe, SheenLobe, SubsurfaceLobe)}
