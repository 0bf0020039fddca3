"""geofix.match: the batch matchers.

Each matches a problem's primary field only: the further fields of a several-sensor
mission (:attr:`geofix.problem.MatchProblem.fields`) are weighed by the recursive
filters PMF, PF and MPF.
"""
