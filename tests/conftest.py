"""Suite-wide settings.

Every hypothesis test is derandomized and keeps no example database, so that a run on any
machine draws the same examples as CI did: a property that fails is a reproducible failure of
the code, found again by the next run, and fixed with a regression example; it never turns a
later run red at random. (Tests that set their own ``@settings`` keep this unless they say
otherwise.)
"""

from hypothesis import settings

settings.register_profile("telesmooth", derandomize=True, database=None)
settings.load_profile("telesmooth")
