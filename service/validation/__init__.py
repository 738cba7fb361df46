"""Left-right consistency: the inner check and the validity codes it produces."""

from service.validation.codes import Validity
from service.validation.inner_check import LR_CHECK_THRESHOLD, inner_check

__all__ = ["LR_CHECK_THRESHOLD", "Validity", "inner_check"]
