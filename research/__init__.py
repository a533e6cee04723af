"""The finished studies (research/README.md): their drivers, reports and committed outputs.
Not part of the sebvs package; a package only so that the studies and research/tests can
import each other (`from research.sensors.sensor_study import ...`) from the checkout."""
