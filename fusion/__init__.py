"""Pure math of rescue-companion: camera model, geolocation, pose interpolation,
tracker and victim registry. numpy, scipy and filterpy only: no I/O, no OpenCV,
no pymavlink."""
