"""Operations on the device: systemd notification, on-disk event recording, live terminal view."""
