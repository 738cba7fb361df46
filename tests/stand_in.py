"""What a stand-in for the Matcher borrows from the real one, so the service checks requests as in production.

The service asks its matcher for the search range and memory plan of a request before queueing it
(service/api/inference.py); a stand-in that holds the shipped ``manifest`` answers with the Matcher's own
rule by deriving from :class:`MatcherRules`.
"""

from __future__ import annotations


class MatcherRules:
    """``Matcher.search_range`` and ``Matcher.plan`` for an object with a ``manifest``."""

    def search_range(self, width: int, options):
        from service.matcher import Matcher

        return Matcher.search_range(self, width, options)

    def plan(self, height: int, width: int, options=None):
        from service.matcher import Matcher

        return Matcher.plan(self, height, width, options)
