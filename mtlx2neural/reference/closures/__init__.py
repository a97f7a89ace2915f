"""One module per pbrlib closure; ``LOBE_CLASSES`` maps a node category to its lobe."""

from mtlx2neural.reference.closures.conductor import ConductorLobe
from mtlx2neural.reference.closures.dielectric import DielectricLobe
from mtlx2neural.reference.closures.diffuse import (
    BurleyLobe,
    OrenNayarLobe,
    TranslucentLobe,
)
from mtlx2neural.reference.closures.generalized_schlick import GeneralizedSchlickLobe
from mtlx2neural.reference.closures.sheen import SheenLobe
from mtlx2neural.reference.closures.subsurface import SubsurfaceLobe

LOBE_CLASSES = {cls.category: cls for cls in (
    ConductorLobe, DielectricLobe, BurleyLobe, OrenNayarLobe, TranslucentLobe,
    GeneralizedSchlickLobe, SheenLobe, SubsurfaceLobe)}
