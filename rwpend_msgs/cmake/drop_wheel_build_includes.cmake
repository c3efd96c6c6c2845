# Removes INTERFACE_INCLUDE_DIRECTORIES entries that start with /opt/python/
# from every imported target of this directory (see ../shared/ENVIRONMENT.md:
# the PyPI ROS 2 wheels carry their build machine's Python include paths).
function(rwpend_drop_wheel_build_includes)
  get_property(_targets DIRECTORY ${CMAKE_CURRENT_SOURCE_DIR} PROPERTY IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc)
      set(_kept "")
      foreach(_d IN LISTS _inc)
        if(NOT _d MATCHES "^/opt/python/")
          list(APPEND _kept "${_d}")
        endif()
      endforeach()
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
    endif()
  endforeach()
endfunction()
