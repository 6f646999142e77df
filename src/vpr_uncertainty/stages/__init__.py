"""The stage spine: dataset → descriptors → retrieval → uncertainties and evaluation → reports.

One module per stage, in the style of hloc: a function taking the stage's named configuration (a frozen
dataclass) and its inputs, writing one artefact and returning a result that holds the artefact's path and the
in-memory output, so that the next stage never reads back what this run wrote. Every artefact follows the cache
protocol of :mod:`vpr_uncertainty.cache` (fingerprint of configuration and input content, atomic writes).

=====================================  ==========================  ============================================
stage                                  artefact                    reused when
=====================================  ==========================  ============================================
:func:`descriptors.extract`            ``descriptors.h5``          per image: same model and content key
:func:`retrieval.search`               ``retrieval.npz``           same options, descriptors and ground truth
:func:`uncertainty.evaluate`           ``uncertainties.npz``       never (it measures the time per query)
:func:`reports.write_reports`          ``results.{json,md}``, plot never (cheap)
=====================================  ==========================  ============================================

:func:`vpr_uncertainty.pipeline.run` composes them for a dataset of images; the ``extract`` and ``retrieve``
commands run one stage each.
"""

from vpr_uncertainty.stages.descriptors import DescriptorsConfig, DescriptorsResult, extract
from vpr_uncertainty.stages.reports import ReportsResult, write_reports
from vpr_uncertainty.stages.retrieval import RetrievalConfig, RetrievalResult, search
from vpr_uncertainty.stages.uncertainty import UncertaintyConfig, UncertaintyResult, evaluate

__all__ = [
    "DescriptorsConfig",
    "DescriptorsResult",
    "ReportsResult",
    "RetrievalConfig",
    "RetrievalResult",
    "UncertaintyConfig",
    "UncertaintyResult",
    "evaluate",
    "extract",
    "search",
    "write_reports",
]
