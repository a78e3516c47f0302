"""
The field monitor: the correction node's check of its own calibration while the robot runs.

- :mod:`.blocks`: the corrected stream cut into blocks one way (:class:`BlockCutter`),
  summarised (:class:`Block`), and the sums of a still period (:class:`Run`);
- :mod:`.still`: still, moving or frozen, block by block (the calibration's detector
  family, with the gyro's zero measured from the data alone);
- :mod:`.inertial`: rest in the inertial sense (a lift, a vehicle, a ship is not a rest);
- :mod:`.mean_noise`: the noise of a period's mean from the data's own batch means;
- :mod:`.prior`: the allowance and the temperature coefficient (history or datasheet);
- :mod:`.gyro_bias`: the gyro bias re-estimated at rest, never from motion or a turn;
- :mod:`.health`: the corrected acceleration at rest against gravity, and the
  temperature against the calibrated range, with a stated false-alarm rate;
- :mod:`.field`: :class:`FieldMonitor`, all of it together (node and CLI share it).

numpy and the standard library only (no scipy: the correction node stays lean).
"""

from .blocks import Block, BlockCutter, Run
from .field import corrected_arrays, FieldMonitor, MonitorSettings
from .gyro_bias import GyroBiasTracker
from .health import CalibrationHealth, ErrorModel, HealthResult
from .still import StillDetector

__all__ = ['Block', 'BlockCutter', 'CalibrationHealth', 'ErrorModel', 'FieldMonitor',
           'GyroBiasTracker', 'HealthResult', 'MonitorSettings', 'Run', 'StillDetector',
           'corrected_arrays']
