"""The LED device: ``cmd/leds`` in, lit LEDs out (the thesis HAL's LED access functions)."""
