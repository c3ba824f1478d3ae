from bgap.runner.numerics import command

main = command("bgap.commands.run")
if __name__ == "__main__":
    main()
