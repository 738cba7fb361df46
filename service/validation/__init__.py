"""Left-right consistency: the inner check and the validity codes it produces."""

from service.validation.codes import Validity
from service.validation.inner_check import inner_check

__all__ = ["Validity", "inner_check"]
