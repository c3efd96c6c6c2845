/*
 * The firmware's version: sent in HELLO_REPLY (fw_major, fw_minor, fw_patch; PROTOCOL.md
 * "Messages") and named in the emulator's status lines (rw_fw_version()).
 */
#ifndef RW_VERSION_H
#define RW_VERSION_H

#define RW_FW_MAJOR 1
#define RW_FW_MINOR 1
#define RW_FW_PATCH 0

#define RW_STR_(x) #x
#define RW_STR(x) RW_STR_(x)
#define RW_FW_VERSION_STRING RW_STR(RW_FW_MAJOR) "." RW_STR(RW_FW_MINOR) "." RW_STR(RW_FW_PATCH)

#endif /* RW_VERSION_H */
