/* The firmware's version (GET_INFO, the USB device descriptor's bcdDevice: one digit each for minor and patch). */
#ifndef ROTOSCAN_FIRMWARE_VERSION_H_
#define ROTOSCAN_FIRMWARE_VERSION_H_

#define FW_VERSION_MAJOR 0
#define FW_VERSION_MINOR 1
#define FW_VERSION_PATCH 0

#endif /* ROTOSCAN_FIRMWARE_VERSION_H_ */
