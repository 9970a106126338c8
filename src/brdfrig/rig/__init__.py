"""Device drivers behind small interfaces: GRBL turntable over pyserial, gphoto2 and watched-folder cameras."""
