"""Report each cause of bad input once, not once per message (no rclpy).

A node keeps running on bad input; at 30 Hz an error per frame would bury the one
line that says what to fix. `report` logs a cause the first time it is seen (and
again after `clear`, i.e. once per episode); `clear` logs that the input recovered.
"""


class ProblemLog:
    def __init__(self, error, info):
        """error, info: callables taking one string (e.g. a ROS logger's methods)."""
        self._error = error
        self._info = info
        self.active = {}  # cause -> message
        self.counts = {}  # cause -> occurrences since the cause was first reported

    def report(self, cause, message):
        self.counts[cause] = self.counts.get(cause, 0) + 1
        if cause not in self.active:
            self.active[cause] = message
            self._error(message)

    def clear(self, *causes):
        """Mark causes (all if none given) as resolved."""
        for cause in causes or list(self.active):
            if self.active.pop(cause, None) is not None:
                self._info(f"input OK again ({cause}; {self.counts.pop(cause, 0)} bad messages)")
