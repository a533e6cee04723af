"""Sensor models on physical light: the frame camera (EMVA 1288) and light units."""
